"""A local Ray that fails or hangs while it starts: the launcher kills it and starts it again.

The fault is injected into the launcher's real `ray.init` by a `sitecustomize` module on
PYTHONPATH (written here, loaded only by the launcher's processes): on the first start,
or on every start, `ray.init` raises, or starts the real Ray and then never returns. The
servers, COMMAND and the Ray of the retry are all real (env_server/tools/ray/watchdog.py
is what is checked).
"""

from __future__ import annotations

import os
import sys
import textwrap

import pytest
from test_ray import Launcher

# Alone on the machine, as test_ray.py: its 20 s bound is on a real Ray's start.
pytestmark = pytest.mark.serial

SITECUSTOMIZE = textwrap.dedent(
    """
    import importlib.abc, importlib.machinery, os, sys, time

    MODE = os.environ.get("TEST_RAY_INIT_FAULT", "")
    FIRST = os.environ.get("ENV_SERVER_RAY_START_ATTEMPT", "1") == "1"

    class Finder(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path, target=None):
            if name != "ray":
                return None
            sys.meta_path.remove(self)
            spec = importlib.machinery.PathFinder.find_spec(name, path)
            run = spec.loader.exec_module

            def exec_module(module):
                run(module)
                real = module.init

                def init(*args, **kwargs):
                    if MODE.startswith("raise"):
                        raise RuntimeError("injected by test_ray_start.py")
                    real(*args, **kwargs)
                    with open(os.environ["TEST_RAY_SESSION_FILE"], "w") as f:
                        f.write(module._private.worker._global_node.session_name)
                    time.sleep(3600)

                module.init = init

            spec.loader.exec_module = exec_module
            return spec

    if MODE == "raise-always" or (MODE and FIRST):
        sys.meta_path.insert(0, Finder())
    """
)


def launcher_with_fault(tmp_path, mode: str, *args: str) -> Launcher:
    (tmp_path / "sitecustomize.py").write_text(SITECUSTOMIZE)
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(tmp_path), os.environ.get("PYTHONPATH", "")]),
        "TEST_RAY_INIT_FAULT": mode,
        "TEST_RAY_SESSION_FILE": str(tmp_path / "session"),
    }
    env.pop("ENV_SERVER_RAY_START_ATTEMPT", None)
    return Launcher(*args, env=env)


def processes_naming(text: str) -> list[int]:
    """Live processes whose command line contains `text` (a Ray session's name is in each of its own)."""
    found = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/cmdline", "rb") as f:
                    if text.encode() in f.read():
                        found.append(int(entry))
            except OSError:
                continue
    return found


EXIT_7 = [sys.executable, "-c", "import sys; sys.exit(7)"]


@pytest.mark.parametrize("mode", ["raise", "hang"])
def test_a_local_ray_that_fails_to_start_is_started_again(tmp_path, mode):
    # 20 s: the real ray.init took 5-6 s with four busy loops on this machine's 2 cores.
    launcher = launcher_with_fault(tmp_path, mode, "--num-servers", "1", "--ray-start-timeout", "20", "--", *EXIT_7)
    code = launcher.finish(400)
    out = launcher.output()
    assert code == 7, out
    why = (
        "the local Ray failed to start: RuntimeError: injected by test_ray_start.py"
        if mode == "raise"
        else "--ray-start-timeout: expected a local Ray up within 20 s, got no answer"
    )
    assert f"{why} (attempt 1 of 3)" in out, out
    assert "Ray up in" in out and "(attempt 2)" in out, out
    assert len(launcher.servers()) == 1, out
    if mode == "hang":  # the first Ray had started: none of its processes outlive the retry
        session = (tmp_path / "session").read_text()
        assert session and not processes_naming(session), (session, processes_naming(session))


def test_a_local_ray_that_never_starts_ends_the_launcher_after_three_tries(tmp_path):
    launcher = launcher_with_fault(tmp_path, "raise-always", "--num-servers", "1", "--", *EXIT_7)
    code = launcher.finish(120)
    out = launcher.output()
    assert code == 2, out
    for n in (1, 2):
        assert f"(attempt {n} of 3); 0 processes it left killed, starting it again" in out, out
    assert "injected by test_ray_start.py (attempt 3 of 3); giving up" in out, out
    assert not launcher.stdout, launcher.stdout
