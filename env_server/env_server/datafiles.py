"""Make kwargs that name a file on the server's disk, resolved only inside the directories
the operator allows.

An env's loader must not become a way to probe or read the server's disk: a
FileNotFoundError says whether a path exists, and an XML or HDF5 parser's error quotes
the file's contents. So every kwarg whose name says it is a file (`xml_file` of the
gymnasium and MO-Gymnasium MuJoCo envs, `clip_path` of humanoid-mocap, `model_path`,
and any other name ending in `file`, `path` or `dir`, at any depth of kwargs_json) goes
through `DataDirs.resolve` before any Task sees it:

- a relative name is looked up in each allowed directory in turn (the shipped assets
  first, so gymnasium's own `xml_file="ant.xml"` still means its file);
- an absolute name, and every candidate, is resolved (symlinks and `..`) and must lie
  inside an allowed directory and be a regular file;
- anything else is PERMISSION_DENIED with one message, whether the path exists or not.

The Task receives the resolved absolute path; `registry.construct` turns a loader that
fails on an allowed file into INVALID_ARGUMENT naming the kwarg, never quoting the file.
"""

from __future__ import annotations

import importlib.util
import os
import pathlib
import re
from collections.abc import Iterable, Mapping
from typing import Any

from env_server.errors import InvalidArgument, PermissionDenied, quote

FILE_KWARG = re.compile(r"(?:^|_)(?:file|path|dir)$")
"""Kwarg names that name a file: xml_file, clip_path, model_path, file, data_dir, ..."""

# Asset directories of the packages the server wraps (package, folder inside it): their
# files are public, and gymnasium's and MO-Gymnasium's xml_file names are relative to them.
_PACKAGE_ASSETS = (
    ("gymnasium", "envs/mujoco/assets"),
    ("mo_gymnasium", "envs/mujoco/assets"),
    ("gymnasium_robotics", "envs/assets"),
)


def shipped_asset_dirs() -> list[str]:
    """The shipped clips and the wrapped packages' asset folders that are installed."""
    dirs = [str(pathlib.Path(__file__).parent / "mocap" / "clips")]
    for package, folder in _PACKAGE_ASSETS:
        spec = importlib.util.find_spec(package)  # finds without importing the package
        if spec is not None and spec.submodule_search_locations:
            dirs.append(os.path.join(list(spec.submodule_search_locations)[0], folder))
    return [d for d in dirs if os.path.isdir(d)]


def file_kwargs(kwargs: Mapping[str, Any], prefix: str = "") -> list[str]:
    """Dotted names of the file kwargs in `kwargs` (nested dicts included), with a value."""
    names = []
    for name, value in kwargs.items():
        if isinstance(value, Mapping):
            names += file_kwargs(value, f"{prefix}{name}.")
        elif FILE_KWARG.search(str(name)) and value is not None:
            names.append(prefix + str(name))
    return names


class DataDirs:
    """The directories whose files clients may name in file kwargs."""

    def __init__(self, extra: Iterable[str] = ()) -> None:
        roots = [*shipped_asset_dirs(), *extra]
        self.roots = tuple(dict.fromkeys(os.path.realpath(d) for d in roots))

    def _inside(self, real: str) -> bool:
        return any(os.path.commonpath([real, root]) == root for root in self.roots)

    def resolve(self, name: str, value: Any) -> str:
        """The real path of the allowed file `value` names; PermissionDenied for anything else."""
        if not isinstance(value, str):
            raise InvalidArgument(f"kwargs_json: {name}: expected a file name (a string), got {quote(value)}")
        candidates = [value] if os.path.isabs(value) else [os.path.join(root, value) for root in self.roots]
        for candidate in candidates:
            try:
                real = os.path.realpath(candidate)
                if self._inside(real) and os.path.isfile(real):
                    return real
            except (OSError, ValueError):  # a NUL byte, a name too long: no such file either
                continue
        # One message whatever the reason: missing, outside, a directory, a dangling link.
        raise PermissionDenied(
            f"kwargs_json: {name}: expected a file inside this server's data directories (the shipped "
            f"assets and each --data-dir), got {quote(value)}, which is not one"
        )

    def resolve_kwargs(self, kwargs: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
        """A copy of `kwargs` with every file kwarg replaced by its resolved path."""
        out: dict[str, Any] = {}
        for name, value in kwargs.items():
            if isinstance(value, Mapping):
                out[name] = self.resolve_kwargs(value, f"{prefix}{name}.")
            elif FILE_KWARG.search(str(name)) and value is not None:
                out[name] = self.resolve(prefix + str(name), value)
            else:
                out[name] = value
        return out
