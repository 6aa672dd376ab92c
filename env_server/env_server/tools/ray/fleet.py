"""The server actors and the address file that lists those that are up (see Fleet).

The launcher (launcher.py) starts the actors; a Fleet watches them, rewrites the file
when one goes down or comes back, and stops them at the end.
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from dataclasses import dataclass
from typing import Any

RETRY_S = 0.5
"""Pause before asking a restarting actor for its address again."""

SLOW_RESTART_S = 60.0
"""A server down this long is reported (once) as stuck: usually no node has the CPUs it needs."""


class LaunchError(Exception):
    """A server or the cluster could not be brought up; the message says which and why."""


def write_address_file(path: str, addresses: list[str], total: int) -> None:
    """Replace `path` with the up servers' addresses, atomically: readers see the old file or the new one."""
    directory = os.path.dirname(os.path.abspath(path))
    fd, tmp = tempfile.mkstemp(prefix=".env-servers-", dir=directory)
    try:
        with os.fdopen(fd, "w") as f:
            f.write(f"# env servers from python -m env_server.tools.ray: {len(addresses)} of {total} up\n")
            f.writelines(f"{a}\n" for a in addresses)
        os.replace(tmp, path)
    except BaseException:
        os.unlink(tmp)
        raise


def log(message: str) -> None:
    """A line of the launcher's on stderr (agent/tests/ray.rs reads the up and back lines)."""
    print(f"env_server.tools.ray: {message}", file=sys.stderr, flush=True)


@dataclass
class _Slot:
    """One server actor and what the launcher last heard from it."""

    index: int
    actor: Any
    address: str | None = None
    pending: Any = None  # ObjectRef of the call in flight: address() while starting, wait() while up
    waiting: bool = False  # pending is wait()
    retry_at: float = 0.0
    starts: int = 0
    down_since: float | None = None  # when the server was last seen going down


class Fleet:
    """N server actors and the address file listing those that are up.

    Each actor has one call in flight: `address()` while it (re)starts, which returns once
    its server listens, then `wait()`, which fails (or returns) when the server or the actor
    dies. So a death is seen as soon as Ray sees it, the address leaves the file, and the
    next `address()` call returns the restarted server's new address.
    """

    def __init__(self, ray: Any, actors: list[Any], path: str) -> None:
        self._ray = ray
        self.slots = [_Slot(i, actor) for i, actor in enumerate(actors)]
        self.path = path
        self._written: list[str] | None = None

    def addresses(self) -> list[str]:
        return [s.address for s in self.slots if s.address is not None]

    def all_up(self) -> bool:
        return all(s.address is not None for s in self.slots)

    def _write(self) -> None:
        addresses = self.addresses()
        if addresses != self._written:
            write_address_file(self.path, addresses, len(self.slots))
            self._written = addresses

    def poll(self, timeout: float) -> None:
        """Wait up to `timeout` s for news from any actor and bring the file up to date."""
        now = time.monotonic()
        for slot in self.slots:
            if slot.pending is None and now >= slot.retry_at:
                slot.pending, slot.waiting = slot.actor.address.remote(), False
            if slot.down_since is not None and now - slot.down_since > SLOW_RESTART_S:
                log(
                    f"server {slot.index} still down after {SLOW_RESTART_S:g} s: Ray has not restarted its actor "
                    "(is there a node with --cpus-per-server CPUs free?)"
                )
                slot.down_since = None
        refs = [s.pending for s in self.slots if s.pending is not None]
        if not refs:
            time.sleep(timeout)
            return
        ready, _ = self._ray.wait(refs, num_returns=len(refs), timeout=timeout)
        ready_ids = {r.hex() for r in ready}
        for slot in self.slots:
            if slot.pending is not None and slot.pending.hex() in ready_ids:
                self._settle(slot)
        self._write()

    def _settle(self, slot: _Slot) -> None:
        ref, slot.pending = slot.pending, None
        try:
            result = self._ray.get(ref)
        except self._ray.exceptions.RayActorError as exc:
            if exc.actor_init_failed:
                raise LaunchError(f"server {slot.index} could not start: {exc}") from None
            result = exc
        except self._ray.exceptions.RayError as exc:
            result = exc
        if slot.waiting:
            why = f"exited with code {result}" if isinstance(result, int) else "lost its actor"
            log(f"server {slot.index} at {slot.address} {why}; Ray restarts it")
            slot.address = None
            slot.down_since = time.monotonic()
            slot.retry_at = time.monotonic() + RETRY_S
        elif isinstance(result, Exception):
            slot.retry_at = time.monotonic() + RETRY_S  # restarting; ask again
        else:
            slot.down_since = None
            slot.address, pid, node = result
            slot.starts += 1
            verb = "up" if slot.starts == 1 else "back"
            log(f"server {slot.index} {verb} at {slot.address} (pid {pid}, node {node[:12]})")
            slot.pending, slot.waiting = slot.actor.wait.remote(), True

    def stop(self) -> None:
        """Stop every server (SIGTERM, so sessions close) and end the actors for good."""
        refs = []
        for slot in self.slots:
            try:
                refs.append(slot.actor.stop.remote())
            except Exception:  # an actor that is gone already has nothing to stop
                pass
        try:
            self._ray.wait(refs, num_returns=len(refs), timeout=15)
        except Exception:
            pass
        for slot in self.slots:
            try:
                self._ray.kill(slot.actor, no_restart=True)
            except Exception:
                pass
