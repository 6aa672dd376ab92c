"""The package's layout rules: the client imports only shared.py of the server, the
server no tool, and shared.py's list of shipped env ids is the registry's.

Imports run in a fresh interpreter, so what other tests imported does not count.
"""

from __future__ import annotations

import importlib.util
import subprocess
import sys

from env_server.envs import REGISTRY
from env_server.shared import SHIPPED_ENV_IDS

CLIENT = ("env_server.client", "env_server.remote", "env_server.connection", "env_server.trained_policy")
SHARED = ("env_server.shared",)


def loaded_by(modules: tuple[str, ...]) -> set[str]:
    """The env_server modules that importing `modules` loads beyond `import env_server`."""
    code = (
        "import sys, env_server\n"
        "before = set(sys.modules)\n"
        f"for name in {list(modules)!r}:\n"
        "    __import__(name)\n"
        "print('\\n'.join(m for m in set(sys.modules) - before if m.startswith('env_server')))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    return set(out.split())


def test_the_client_imports_no_server_internals():
    modules = CLIENT if _has_torch() else CLIENT[:-1]  # trained_policy needs the `policy` extra
    loaded = loaded_by(modules)
    allowed = set(CLIENT) | set(SHARED)
    assert {m for m in loaded if m not in allowed and not m.startswith("env_server._proto")} == set()


def test_the_server_imports_no_tool():
    loaded = loaded_by(("env_server.__main__", "env_server.server", "env_server.service"))
    assert {m for m in loaded if m.startswith("env_server.tools")} == set()


def test_the_shipped_env_ids_are_the_registry_in_its_order():
    assert SHIPPED_ENV_IDS == tuple(REGISTRY)


def _has_torch() -> bool:
    return all(importlib.util.find_spec(name) is not None for name in ("torch", "safetensors"))
