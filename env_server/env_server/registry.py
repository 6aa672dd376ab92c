"""Resolve env ids to Task factories.

Three sources, merged once at startup:
  1. the shipped REGISTRY (env_server/envs/__init__.py), one line per env;
  2. the `env_server.envs` entry-point group, so users register Tasks from their own
     package without editing the server:
         [project.entry-points."env_server.envs"]
         my-env = "my_pkg.envs:MyTask"
  3. prefix adapters, resolved on demand: `gym:<gymnasium id>`, `mo:<MO-Gymnasium id>`,
     `dmc:<domain>-<task>` (the first "-" splits domain from task; dm_control domains
     use underscores, e.g. dmc:ball_in_cup-catch).
Listing reads class attributes only and never constructs a simulator.
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import importlib.metadata
import inspect
import logging
from collections.abc import Callable, Iterable, Mapping
from typing import Any

from env_server.datafiles import file_kwargs
from env_server.errors import QUOTE_LIMIT, EnvServerError, InvalidArgument, NotFound, quote
from env_server.task import Objective, Task

ENTRY_POINT_GROUP = "env_server.envs"

log = logging.getLogger(__name__)


class RegistryError(Exception):
    """The registry cannot be built (entry-point clash or a bad entry point); fatal at startup."""


@dataclasses.dataclass(frozen=True)
class EnvEntry:
    """A resolvable env id: what to list and how to construct it."""

    env_id: str
    description: str
    objectives: tuple[Objective, ...]
    factory: Callable[..., Task]
    origin: str  # "shipped", "entry point <name> = <value>", or "prefix <prefix>:"


@dataclasses.dataclass(frozen=True)
class Prefix:
    """A family of env ids handled by one adapter."""

    prefix: str
    pattern: str
    task_class: type[Task]
    resolve: Callable[[str], Callable[..., Task]]  # rest of the id -> factory; raises NotFound


def _near(name: str, candidates: Iterable[str]) -> str:
    if len(name) > QUOTE_LIMIT:  # no id is that long, and difflib is quadratic
        return ""
    close = difflib.get_close_matches(name, list(candidates), n=5, cutoff=0.5)
    return f"; did you mean {', '.join(close)}?" if close else ""


def _resolve_gym(rest: str) -> Callable[..., Task]:
    import gymnasium

    from env_server.backends.gymnasium import GymTask

    if rest not in gymnasium.registry:
        raise NotFound(f"env_id: unknown gymnasium id {quote('gym:' + rest)}{_near(rest, gymnasium.registry)}")
    return functools.partial(GymTask, rest)


def _resolve_mo(rest: str) -> Callable[..., Task]:
    import gymnasium
    import mo_gymnasium  # noqa: F401  (registers the MO envs into gymnasium.registry)

    from env_server.backends.mo_gymnasium import MoGymTask

    if rest not in gymnasium.registry:
        raise NotFound(f"env_id: unknown MO-Gymnasium id {quote('mo:' + rest)}{_near(rest, gymnasium.registry)}")
    return functools.partial(MoGymTask, rest)


def _resolve_dmc(rest: str) -> Callable[..., Task]:
    from dm_control import suite

    from env_server.backends.dm_control import DmcTask

    domain, _, task = rest.partition("-")
    known = [f"{d}-{t}" for d, t in suite.ALL_TASKS]
    if (domain, task) not in suite.ALL_TASKS:
        raise NotFound(
            f"env_id: unknown dm_control task {quote('dmc:' + rest)} (expected dmc:<domain>-<task>){_near(rest, known)}"
        )
    return functools.partial(DmcTask, domain, task)


def _prefixes() -> tuple[Prefix, ...]:
    from env_server.backends.dm_control import DmcTask
    from env_server.backends.gymnasium import GymTask
    from env_server.backends.mo_gymnasium import MoGymTask

    return (
        Prefix("gym", "gym:<gymnasium id>", GymTask, _resolve_gym),
        Prefix("mo", "mo:<MO-Gymnasium id>", MoGymTask, _resolve_mo),
        Prefix("dmc", "dmc:<domain>-<task>", DmcTask, _resolve_dmc),
    )


def _entry_points() -> list[importlib.metadata.EntryPoint]:
    return sorted(importlib.metadata.entry_points(group=ENTRY_POINT_GROUP), key=lambda ep: ep.name)


class Registry:
    """Every env id the server can make."""

    def __init__(self, shipped: Mapping[str, type[Task]] | None = None, load_entry_points: bool = True) -> None:
        if shipped is None:
            from env_server.envs import REGISTRY as shipped
        self._entries: dict[str, EnvEntry] = {
            env_id: EnvEntry(env_id, cls.description, tuple(cls.objectives), cls, "shipped")
            for env_id, cls in shipped.items()
        }
        self.prefixes = _prefixes()
        if load_entry_points:
            for ep in _entry_points():
                self._add_entry_point(ep)

    def _add_entry_point(self, ep: importlib.metadata.EntryPoint) -> None:
        origin = f"entry point {ep.name} = {ep.value}"
        if ep.name in self._entries:
            raise RegistryError(
                f"env id '{ep.name}' is registered twice: {self._entries[ep.name].origin} "
                f"and {origin} (group {ENTRY_POINT_GROUP}); rename one"
            )
        if ep.name.split(":", 1)[0] in {p.prefix for p in self.prefixes} and ":" in ep.name:
            raise RegistryError(f"{origin}: ids starting with an adapter prefix are reserved")
        try:
            cls = ep.load()
        except Exception as exc:
            raise RegistryError(f"{origin} failed to load: {type(exc).__name__}: {exc}") from exc
        if not (inspect.isclass(cls) and issubclass(cls, Task)):
            raise RegistryError(f"{origin}: expected a subclass of env_server.task.Task, got {cls!r}")
        self._entries[ep.name] = EnvEntry(ep.name, cls.description, tuple(cls.objectives), cls, origin)

    def entries(self) -> list[EnvEntry]:
        """Shipped and entry-point envs, sorted by id (prefix adapters are unbounded, not listed)."""
        return [self._entries[k] for k in sorted(self._entries)]

    def resolve(self, env_id: str) -> EnvEntry:
        """The entry for env_id; raises NotFound listing close or known ids."""
        entry = self._entries.get(env_id)
        if entry is not None:
            return entry
        head, sep, rest = env_id.partition(":")
        if sep:
            for prefix in self.prefixes:
                if prefix.prefix == head:
                    factory = prefix.resolve(rest)
                    cls = prefix.task_class
                    return EnvEntry(env_id, cls.description, tuple(cls.objectives), factory, f"prefix {head}:")
        hint = _near(env_id, self._entries)
        known = ", ".join(sorted(self._entries))
        patterns = ", ".join(p.pattern for p in self.prefixes)
        raise NotFound(f"env_id: unknown env {quote(env_id)}{hint} (known: {known}; or one of {patterns})")


def construct(entry: EnvEntry, kwargs: Mapping[str, Any]) -> Task:
    """entry.factory(**kwargs), turning a kwargs mismatch, or a loader that fails on a file
    kwarg (already resolved by datafiles.DataDirs), into InvalidArgument naming the kwarg."""
    if inspect.isclass(entry.factory):
        params = inspect.signature(entry.factory).parameters
        if not any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
            accepted = [n for n, p in params.items() if p.kind is not inspect.Parameter.VAR_POSITIONAL]
            for name in kwargs:
                if name not in accepted:
                    raise InvalidArgument(
                        f"kwargs_json: env '{entry.env_id}' has no keyword argument {quote(name)}; accepted: {accepted}"
                    )
    files = file_kwargs(kwargs)
    try:
        return entry.factory(**kwargs)
    except EnvServerError:
        raise
    except Exception as exc:
        if not files:
            if isinstance(exc, TypeError) and kwargs:
                raise _rejected(entry, kwargs, exc) from exc
            raise
        # A loader's error quotes the file (XML element names, HDF5 internals) or its
        # server-side path: the client hears which kwarg, the log gets the rest.
        log.warning("env %s: constructor raised with file kwargs %s", entry.env_id, files, exc_info=exc)
        raise InvalidArgument(
            f"kwargs_json: env '{entry.env_id}' could not be built from the file named by {', '.join(files)} "
            f"({type(exc).__name__}; expected a file this env can load, the server's log has the details)"
        ) from exc


def _rejected(entry: EnvEntry, kwargs: Mapping[str, Any], exc: TypeError) -> InvalidArgument:
    return InvalidArgument(
        f"kwargs_json: env '{entry.env_id}' rejected keyword arguments {quote(sorted(kwargs))}: {quote(str(exc), 200)}"
    )
