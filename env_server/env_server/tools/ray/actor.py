"""One env_server process owned by one Ray actor: it starts it, reports its address, and dies with it.

The server runs as a child process of the actor (`python -m env_server --host <node IP>
--port 0`), not inside the actor, so that it keeps its own signal handling and asyncio loop
and a stop is a plain SIGTERM. A dead server and a dead actor then look the same to Ray: a
watchdog thread ends the actor's process when its server exits, and Ray restarts the actor
(`max_restarts=-1`), whose constructor starts a new server on a new port. The other way
round, the server gets SIGTERM from the kernel when the actor's process dies
(PR_SET_PDEATHSIG), so a killed actor or a removed node leaves no orphan server behind.

A server that cannot start (a bad flag, a missing token file) makes the constructor raise:
Ray does not restart an actor whose constructor failed, so the launcher reports the error
instead of restarting a misconfigured server forever.
"""

from __future__ import annotations

import collections
import ctypes
import os
import queue
import signal
import subprocess
import sys
import threading

import ray

LISTEN_TIMEOUT_S = 60.0
"""How long a starting server may take to print its LISTENING line."""

STOP_GRACE_S = 10.0
"""How long a stopped server may take to close its sessions before it is killed."""

_PR_SET_PDEATHSIG = 1
# Looked up here, not between fork and exec, where only async-signal-safe work is wise.
_prctl = ctypes.CDLL(None, use_errno=True).prctl if sys.platform.startswith("linux") else None


def _die_with_parent() -> None:
    """In the server child, before exec: SIGTERM when the actor's process dies (Linux only; as Ray does)."""
    if _prctl is not None:
        _prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)


class ServerActor:
    """A Ray actor body (the launcher wraps it with `ray.remote`) owning one env_server process."""

    def __init__(self, server_args: list[str]) -> None:
        host = ray.util.get_node_ip_address()
        self._stopping = False
        self._stderr_tail: collections.deque[str] = collections.deque(maxlen=20)
        self._proc = subprocess.Popen(
            [sys.executable, "-m", "env_server", "--host", host, "--port", "0", *server_args],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            preexec_fn=_die_with_parent,
        )
        self._stderr_thread = threading.Thread(target=self._forward_stderr, daemon=True)
        self._stderr_thread.start()
        self._address = self._read_listening(host)
        threading.Thread(target=self._watch, daemon=True).start()

    def _forward_stderr(self) -> None:
        """Copy the server's log to the actor's stderr (Ray's worker log), keeping the tail for errors."""
        for line in self._proc.stderr:
            self._stderr_tail.append(line.rstrip())
            sys.stderr.write(line)
            sys.stderr.flush()

    def _read_listening(self, host: str) -> str:
        """The `host:port` of the server's `LISTENING host:port` line; raises if it never comes."""
        lines: queue.Queue[str] = queue.Queue()
        threading.Thread(target=lambda: lines.put(self._proc.stdout.readline()), daemon=True).start()
        try:
            line = lines.get(timeout=LISTEN_TIMEOUT_S)
        except queue.Empty:
            self._proc.kill()
            line = ""
        if line.startswith("LISTENING "):
            return line.split(None, 1)[1].strip()
        code = self._proc.wait()
        self._stderr_thread.join(timeout=2)
        tail = "\n".join(self._stderr_tail)
        raise RuntimeError(
            f"env_server on {host}: expected a 'LISTENING host:port' line within {LISTEN_TIMEOUT_S:g} s, "
            f"got {line.strip()!r} and exit code {code}; its stderr ended with:\n{tail}"
        )

    def _watch(self) -> None:
        """End this actor's process when its server exits unasked, so that Ray restarts both."""
        code = self._proc.wait()
        if not self._stopping:
            print(f"env_server {self._address} exited with code {code}; ending its actor", file=sys.stderr, flush=True)
            os._exit(1)

    def address(self) -> tuple[str, int, str]:
        """The server's `host:port`, its process id and the id of the Ray node it runs on.

        Raises once the server has exited: the actor is about to end, and its old address
        must not be mistaken for the restarted server's.
        """
        if self._proc.poll() is not None:
            raise RuntimeError(f"env_server {self._address} has exited; its actor is restarting")
        return self._address, self._proc.pid, ray.get_runtime_context().get_node_id()

    def wait(self) -> int:
        """Block until the server exits; its exit code (usually the actor dies first, failing this call)."""
        return self._proc.wait()

    def stop(self) -> int:
        """SIGTERM the server (it closes its sessions), SIGKILL after STOP_GRACE_S; its exit code."""
        self._stopping = True
        self._proc.terminate()
        try:
            return self._proc.wait(timeout=STOP_GRACE_S)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            return self._proc.wait()
