"""Bounds on the launcher's own waits on Ray, and the retry of a local Ray that does not start.

`ray.init` and `ray.shutdown` take no timeout, and now and then a local Ray on a small
machine does not come up: its raylet misses Ray's 30 s window to register (Ray then
raises) or `ray.init` never returns (a CI run waited 300 s on one). A `Deadline` runs a
callback on its own thread when a wait outlives its bound, since the waiting thread is
stuck inside Ray. For a local Ray, which this launcher owns, the callback (or the
exception) kills every process the launcher started and runs the launcher again from
the start (`exec`, same pid, same arguments) up to `ATTEMPTS` times, the retry a user
would otherwise do by hand; a cluster the launcher only connects to is not restarted.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
from collections.abc import Callable
from types import TracebackType

ATTEMPT_ENV = "ENV_SERVER_RAY_START_ATTEMPT"
"""Which start of a local Ray this run of the launcher is (1 when unset); set across `exec`."""

ATTEMPTS = 3
"""Starts of a local Ray before the launcher gives up (exit code 2)."""

_RESTART = threading.Lock()


class Deadline:
    """`with Deadline(seconds, on_expiry):` calls `on_expiry()` on a watchdog thread if the
    block is still running after `seconds`; leaving the block first disarms it."""

    def __init__(self, seconds: float, on_expiry: Callable[[], None]) -> None:
        self._seconds = seconds
        self._on_expiry = on_expiry
        self._done = threading.Event()
        self._thread = threading.Thread(target=self._watch, name="env_server.tools.ray deadline", daemon=True)

    def _watch(self) -> None:
        if not self._done.wait(self._seconds):
            self._on_expiry()

    def __enter__(self) -> Deadline:
        self._thread.start()
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        self._done.set()


def attempt() -> int:
    """This run's start of a local Ray: 1, or the count carried across a retry's `exec`."""
    try:
        return max(1, int(os.environ.get(ATTEMPT_ENV, "1")))
    except ValueError:
        return 1


def descendants(pid: int) -> list[int]:
    """Every live process below `pid`, read from /proc (Linux; elsewhere none are found)."""
    children: dict[int, list[int]] = {}
    try:
        entries = os.listdir("/proc")
    except OSError:
        return []
    for entry in entries:
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as f:
                ppid = int(f.read().rsplit(")", 1)[1].split()[1])
        except (OSError, IndexError, ValueError):
            continue  # exited while listed
        children.setdefault(ppid, []).append(int(entry))
    found, todo = [], list(children.get(pid, []))
    while todo:
        child = todo.pop()
        found.append(child)
        todo.extend(children.get(child, []))
    return found


def kill_descendants() -> int:
    """SIGKILL every process this one started, with theirs (a local Ray's GCS, raylet and
    workers, and the servers); how many there were."""
    doomed = descendants(os.getpid())
    for pid in doomed:
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    return len(doomed)


def restart_or_exit(log: Callable[[str], None], why: str) -> None:
    """A local Ray did not start: kill what it left and run the launcher again, or give up.

    Never returns: `exec` replaces this process (its pid, stdout and stderr stay, so a
    caller waiting on it sees one launcher), or `_exit(2)` after the last attempt.
    """
    _RESTART.acquire()  # a second caller (the main thread, once the kill wakes it) waits for the exec
    n = attempt()
    killed = kill_descendants()
    if n >= ATTEMPTS:
        log(f"{why} (attempt {n} of {ATTEMPTS}); giving up, {killed} processes it left killed")
        sys.stderr.flush()
        os._exit(2)
    log(f"{why} (attempt {n} of {ATTEMPTS}); {killed} processes it left killed, starting it again")
    sys.stdout.flush()
    sys.stderr.flush()
    os.environ[ATTEMPT_ENV] = str(n + 1)
    os.execv(sys.executable, [sys.executable, *sys.orig_argv[1:]])
