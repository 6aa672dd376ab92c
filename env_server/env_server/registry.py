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

A plug-in fails alone. An entry point that does not load (an import error, not a Task,
objectives that are not Objectives) is logged once at startup and listed as unavailable
with its package and reason, and a Make of it is FAILED_PRECONDITION; a constructor that
raises at Make for a reason other than the caller's kwargs (see `construct`) lists the env
as unavailable until a Make of it succeeds. Every other env keeps working. Two ids that
clash still stop the server: which of the two a client meant cannot be guessed.
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import importlib.metadata
import inspect
import logging
import threading
from collections.abc import Callable, Iterable, Mapping
from typing import Any

from env_server.datafiles import file_kwargs
from env_server.errors import (
    QUOTE_LIMIT,
    ConstructorError,
    EnvServerError,
    FailedPrecondition,
    InvalidArgument,
    NotFound,
    quote,
)
from env_server.kwarg_types import check_kwarg_types
from env_server.task import Objective, Task

ENTRY_POINT_GROUP = "env_server.envs"
# Characters of a plug-in's import error that its "unavailable" reason quotes.
REASON_LIMIT = 300

log = logging.getLogger(__name__)


class RegistryError(Exception):
    """The registry cannot be built (two entry points or an entry point and a shipped env
    claim one id, or an id takes an adapter prefix); fatal at startup."""


@dataclasses.dataclass(frozen=True)
class EnvEntry:
    """A resolvable env id: what to list and how to construct it."""

    env_id: str
    description: str
    objectives: tuple[Objective, ...]
    factory: Callable[..., Task]
    origin: str  # "shipped", "entry point <name> = <value>", or "prefix <prefix>:"
    package: str = "env_server"  # the distribution that provides it, with its version
    broken: str = ""  # why the entry point did not load ("" = it did); never made then


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
        self._make_failures: dict[str, str] = {}  # env id -> why its last Make failed
        self._lock = threading.Lock()  # Makes build, and note_make, on executor threads
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
        package = f"{ep.dist.name} {ep.dist.version}" if ep.dist is not None else "an unknown distribution"
        try:
            cls = _load_task_class(ep)
        except _Broken as exc:
            log.error(
                "env %s (package %s, %s) is unavailable: %s",
                ep.name,
                package,
                origin,
                exc.reason,
                exc_info=exc.__cause__,
            )
            self._entries[ep.name] = EnvEntry(ep.name, "", (), _never, origin, package, exc.reason)
            return
        self._entries[ep.name] = EnvEntry(ep.name, cls.description, tuple(cls.objectives), cls, origin, package)

    def unavailable(self, entry: EnvEntry) -> str:
        """Why `entry` cannot be made now, naming its package ("" when it can)."""
        reason = entry.broken or self._make_failures.get(entry.env_id, "")
        return f"{reason} (package {entry.package}, {entry.origin})" if reason else ""

    def listed_description(self, entry: EnvEntry) -> str:
        """The one line `--list` and ListEnvs show: the description, or "unavailable: <why>".

        ListEnvs carries it in EnvInfo.description, so every client that prints the list
        (the agent's `envs` among them) shows why without a proto change."""
        reason = self.unavailable(entry)
        return f"unavailable: {reason}" if reason else entry.description

    def note_make(self, entry: EnvEntry, failure: ConstructorError | None) -> None:
        """Record how a Make of `entry` ended: a ConstructorError lists it as unavailable
        (logged with its traceback once per distinct reason), success lists it again."""
        with self._lock:
            if failure is None:
                self._make_failures.pop(entry.env_id, None)
                return
            reason = f"its constructor raised at the last Make: {failure.reason}"
            new = self._make_failures.get(entry.env_id) != reason
            self._make_failures[entry.env_id] = reason
        if new:
            log.error("env %s (package %s) is unavailable: %s", entry.env_id, entry.package, reason, exc_info=failure)

    def entries(self) -> list[EnvEntry]:
        """Shipped and entry-point envs, sorted by id (prefix adapters are unbounded, not listed)."""
        return [self._entries[k] for k in sorted(self._entries)]

    def resolve(self, env_id: str) -> EnvEntry:
        """The entry for env_id; raises NotFound listing close or known ids, and
        FailedPrecondition naming the package and reason for an entry point that did not load."""
        entry = self._entries.get(env_id)
        if entry is not None:
            if entry.broken:
                # The id is known, so not NOT_FOUND (which says "check the spelling"): the
                # server cannot make it until its operator fixes the package, and
                # FAILED_PRECONDITION is the code clients do not retry for that.
                raise FailedPrecondition(f"env_id: env '{env_id}' is unavailable: {self.unavailable(entry)}")
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


class _Broken(Exception):
    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


def _load_task_class(ep: importlib.metadata.EntryPoint) -> type[Task]:
    """The Task class `ep` names, with listable class attributes; raises _Broken saying why not."""
    try:
        cls = ep.load()
    except Exception as exc:
        # Cut: the reason travels in ListEnvs and in Make's status, whose trailing
        # metadata clients cap at 8-16 KiB; the log keeps the whole of it (the cause).
        message = str(exc)
        if len(message) > REASON_LIMIT:
            message = f"{message[:REASON_LIMIT]}... ({len(message)} characters)"
        raise _Broken(f"failed to load: {type(exc).__name__}: {message}") from exc
    if not (inspect.isclass(cls) and issubclass(cls, Task)):
        raise _Broken(f"expected a subclass of env_server.task.Task, got {quote(cls, REASON_LIMIT)}")
    objectives = cls.objectives
    if not (isinstance(objectives, tuple) and all(isinstance(o, Objective) for o in objectives)):
        raise _Broken(
            f"{cls.__name__}.objectives: expected a tuple of env_server.task.Objective, got {quote(objectives, REASON_LIMIT)}"
        )
    if not isinstance(cls.description, str):
        raise _Broken(f"{cls.__name__}.description: expected a str, got {quote(cls.description, REASON_LIMIT)}")
    return cls


def _never(**kwargs: Any) -> Task:
    raise AssertionError("a broken entry is refused by Registry.resolve before it is built")


def construct(entry: EnvEntry, kwargs: Mapping[str, Any]) -> Task:
    """entry.factory(**kwargs), with the caller's errors as InvalidArgument naming the kwarg.

    The caller's: a keyword the constructor does not take, a value that cannot have the
    type of its parameter's default (kwarg_types), a file kwarg (already resolved by
    datafiles.DataDirs) its loader fails on, and a TypeError or ValueError the
    constructor raises when given kwargs: Python's own convention for "bad argument",
    which is what a constructor validating its kwargs raises. The rule cannot see intent:
    such an error from a bug that only kwargs reach is answered INVALID_ARGUMENT too, so
    the message says so and the log keeps the traceback. Any other exception, or any
    exception without kwargs, is the env's and propagates (INTERNAL). A Task that wants
    its own message raises env_server.errors.InvalidArgument.
    """
    if inspect.isclass(entry.factory):
        params = inspect.signature(entry.factory).parameters
        if not any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
            accepted = [n for n, p in params.items() if p.kind is not inspect.Parameter.VAR_POSITIONAL]
            for name in kwargs:
                if name not in accepted:
                    raise InvalidArgument(
                        f"kwargs_json: env '{entry.env_id}' has no keyword argument {quote(name)}; accepted: {accepted}"
                    )
        check_kwarg_types(entry.env_id, params, kwargs)
    files = file_kwargs(kwargs)
    try:
        return entry.factory(**kwargs)
    except EnvServerError:
        raise
    except Exception as exc:
        if files:
            # A loader's error quotes the file (XML element names, HDF5 internals) or its
            # server-side path: the client hears which kwarg, the log gets the rest.
            log.warning("env %s: constructor raised with file kwargs %s", entry.env_id, files, exc_info=exc)
            raise InvalidArgument(
                f"kwargs_json: env '{entry.env_id}' could not be built from the file named by {', '.join(files)} "
                f"({type(exc).__name__}; expected a file this env can load, the server's log has the details)"
            ) from exc
        if kwargs and isinstance(exc, (TypeError, ValueError)):
            log.warning("env %s: constructor rejected kwargs %s", entry.env_id, sorted(kwargs), exc_info=exc)
            raise InvalidArgument(
                f"kwargs_json: env '{entry.env_id}' rejected keyword arguments {quote(sorted(kwargs))}: "
                f"{type(exc).__name__}: {quote(str(exc), 200)} (if these values are valid, the constructor of "
                f"package {entry.package} has a bug; the server log has the traceback)"
            ) from exc
        raise
