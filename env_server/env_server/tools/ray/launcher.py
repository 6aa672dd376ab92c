"""`python -m env_server.tools.ray --num-servers N [options] [-- COMMAND ...]`: env servers on a Ray cluster.

Starts N env servers as Ray actors spread over the cluster's nodes and restarted when they
fail, writes their addresses to an address file (one `host:port` per line, only the servers
that are up, rewritten atomically whenever one goes down or comes back), then runs COMMAND
with `--server file:PATH` appended, so that `-- agent train --config c.toml` trains on them
and re-reads the file when a server becomes unreachable. COMMAND's output is streamed, its
exit code is the launcher's, and the servers stop when it exits. COMMAND also finds the
file in $ENV_SERVER_ADDRESS_FILE. Without COMMAND the launcher keeps the servers and the
file up until Ctrl-C or SIGTERM, for an agent started elsewhere. With --sweep-shards S,
COMMAND is `agent sweep --config FILE ...`, run as S Ray tasks of one shard each (retried,
and resumed, when a node is lost), then merged into the sweep's front (see sweep.py).
"""

from __future__ import annotations

import argparse
import ipaddress
import logging
import os
import shlex
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from typing import Any

from env_server.tools.ray import sweep

NAMESPACE = "env_server"
"""The Ray namespace of the server actors (named NAME-0 .. NAME-(N-1), --name)."""

RETRY_S = 0.5
"""Pause before asking a restarting actor for its address again."""

SLOW_RESTART_S = 60.0
"""A server down this long is reported (once) as stuck: usually no node has the CPUs it needs."""

_LOOPBACK_ENV = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"


class LaunchError(Exception):
    """A server or the cluster could not be brought up; the message says which and why."""


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m env_server.tools.ray",
        description=__doc__.split("\n\n")[1],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        usage="%(prog)s --num-servers N [options] [-- COMMAND ...]",
    )
    p.add_argument("--num-servers", type=int, required=True, metavar="N", help="env servers to run (>= 1)")
    p.add_argument(
        "--address",
        help="the Ray cluster: its head's host:port, or 'auto' for the one `ray start` made on this machine "
        "(default: $RAY_ADDRESS when set, else a local Ray on 127.0.0.1 that lives as long as this launcher)",
    )
    p.add_argument(
        "--address-file",
        metavar="PATH",
        help="file to keep the up servers' addresses in (default: a temporary file, removed at exit)",
    )
    p.add_argument(
        "--server-args",
        default="",
        metavar="ARGS",
        help="env_server flags for every server, one shell-quoted string, e.g. "
        '"--auth-token-file /etc/mo/tokens --tls-cert c.pem --tls-key k.pem"; files are read on each '
        "server's node. A server binds its node's IP, which env_server refuses off loopback without TLS and a "
        "token or --insecure",
    )
    p.add_argument(
        "--cpus-per-server",
        type=float,
        default=1.0,
        help="Ray CPUs each server actor reserves (default 1; a local Ray gets N times this many)",
    )
    p.add_argument(
        "--name",
        default="env-server",
        help=f"actor name prefix: NAME-0 .. NAME-(N-1) in Ray namespace '{NAMESPACE}' (default env-server)",
    )
    p.add_argument(
        "--startup-timeout",
        type=float,
        default=300.0,
        metavar="S",
        help="seconds to wait for all N servers to listen before giving up (default 300)",
    )
    p.add_argument(
        "--sweep-shards",
        type=int,
        metavar="S",
        help="run COMMAND (`agent sweep --config FILE ...`) as S shards, one Ray task each (retried on node loss, "
        "resuming the shard), then merge them into the front in --sweep-dir/front",
    )
    p.add_argument(
        "--sweep-dir",
        metavar="DIR",
        help="with --sweep-shards: where the shard folders (shard-I-of-S) and the merged front go; every node "
        "must reach it at this path, as it must the address file (--address-file) and COMMAND's files",
    )
    p.add_argument(
        "--cpus-per-shard",
        type=float,
        default=1.0,
        help="Ray CPUs each shard task reserves (default 1; a local Ray gets S times this many more)",
    )
    p.add_argument(
        "--shard-retries",
        type=int,
        default=3,
        metavar="R",
        help="times Ray retries a shard whose node or worker was lost (default 3)",
    )
    return p


@dataclass
class Options:
    """The launcher's parsed command line: its own flags and COMMAND (empty: serve until stopped)."""

    args: argparse.Namespace
    server_args: list[str]
    command: list[str]


def parse(argv: list[str]) -> Options:
    """Split argv at the first `--` into the launcher's flags and COMMAND; exits 2 on bad flags."""
    split = argv.index("--") if "--" in argv else len(argv)
    parser = _parser()
    args = parser.parse_args(argv[:split])
    command = argv[split + 1 :]
    if args.num_servers < 1:
        parser.error(f"--num-servers: expected >= 1, got {args.num_servers}")
    if args.cpus_per_server < 0:
        parser.error(f"--cpus-per-server: expected >= 0, got {args.cpus_per_server}")
    try:
        server_args = shlex.split(args.server_args)
    except ValueError as exc:
        parser.error(f"--server-args: expected a shell-quoted string, got {args.server_args!r} ({exc})")
    taken = [a for a in server_args if a.split("=", 1)[0] in ("--host", "--port", "--list")]
    if taken:
        parser.error(
            f"--server-args: expected env_server flags other than --host, --port and --list (each server binds "
            f"its node's IP and an OS-chosen port), got {taken}"
        )
    if "--" in argv and not command:
        parser.error("expected a COMMAND after '--', got nothing")
    if args.sweep_shards is not None:
        if args.sweep_shards < 1:
            parser.error(f"--sweep-shards: expected >= 1, got {args.sweep_shards}")
        if args.sweep_dir is None:
            parser.error("--sweep-shards: expected --sweep-dir DIR beside it (where the shards go), got none")
        if args.shard_retries < 0:
            parser.error(f"--shard-retries: expected >= 0, got {args.shard_retries}")
        why = sweep.check_command(command)
        if why:
            parser.error(f"--sweep-shards: {why}")
    elif args.sweep_dir is not None:
        parser.error(f"--sweep-dir: expected with --sweep-shards, got it alone ({args.sweep_dir!r})")
    return Options(args, server_args, command)


def _is_loopback(address: str) -> bool:
    host = address.rsplit(":", 1)[0].strip("[]")
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def ray_address(flag: str | None) -> str:
    """The address for `ray.init`: the flag, else $RAY_ADDRESS, else "local" (start one here)."""
    if flag is not None:
        return flag
    return os.environ.get("RAY_ADDRESS") or "local"


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


def _log(message: str) -> None:
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
                _log(
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
            _log(f"server {slot.index} at {slot.address} {why}; Ray restarts it")
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
            _log(f"server {slot.index} {verb} at {slot.address} (pid {pid}, node {node[:12]})")
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


class _Signals:
    """SIGINT/SIGTERM: remembered, and passed on once to COMMAND while it runs.

    COMMAND runs in its own session (so its own process group), so a terminal's Ctrl-C reaches only the launcher,
    which forwards exactly one SIGINT: an agent that takes a second Ctrl-C as "quit now" still
    gets the chance to write its checkpoint and summary.
    """

    def __init__(self) -> None:
        self.received: int | None = None
        self.child: subprocess.Popen | None = None
        self.install()

    def install(self) -> None:
        """(Re)install the handlers; `ray.init` replaces the SIGTERM one with its own, which exits at once."""
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, self._handle)

    def _handle(self, signum: int, _frame: Any) -> None:
        self.received = signum
        if self.child is not None and self.child.poll() is None:
            self.child.send_signal(signum)


def _start_ray(opts: Options) -> Any:
    """Connect to (or start) the cluster; returns the imported `ray` module."""
    address = ray_address(opts.args.address)
    if address == "local" or _is_loopback(address):
        # Ray on Linux rewrites 127.0.0.1 to the machine's network IP when it connects, where a
        # cluster on loopback does not listen; this setting (read when ray is imported) keeps
        # loopback as loopback, so a local Ray and its servers stay off the network.
        os.environ.setdefault(_LOOPBACK_ENV, "0")
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    import ray  # the real Ray: absolute import, after the environment above is set

    kwargs: dict[str, Any] = {
        "namespace": NAMESPACE,
        "include_dashboard": False,
        "log_to_driver": False,  # server logs stay in Ray's worker logs, out of COMMAND's output
        "logging_level": logging.WARNING,
    }
    if address == "local":
        os.environ.pop("RAY_ADDRESS", None)  # ray.init prefers $RAY_ADDRESS over address="local"
        shards = (opts.args.sweep_shards or 0) * opts.args.cpus_per_shard
        kwargs.update(
            num_cpus=max(1, int(-(-(opts.args.num_servers * opts.args.cpus_per_server + shards) // 1))),
            object_store_memory=128 * 1024 * 1024,
        )
    ray.init(address=address, **kwargs)
    return ray


def _start_actors(ray: Any, opts: Options) -> list[Any]:
    from env_server.tools.ray.actor import ServerActor

    remote = ray.remote(ServerActor)
    actors = []
    for i in range(opts.args.num_servers):
        name = f"{opts.args.name}-{i}"
        try:
            actors.append(
                remote.options(
                    name=name,
                    namespace=NAMESPACE,
                    num_cpus=opts.args.cpus_per_server,
                    max_restarts=-1,
                    max_concurrency=4,  # address(), wait() and stop() may run at once
                    scheduling_strategy="SPREAD",
                ).remote(opts.server_args)
            )
        except ValueError as exc:  # the name is taken: another launcher runs on this cluster
            raise LaunchError(
                f"--name: expected an actor name free in Ray namespace '{NAMESPACE}', got {name!r} ({exc})"
            ) from None
    return actors


def run(opts: Options, signals: _Signals) -> int:
    """Bring the servers up, run COMMAND (or wait for a signal), stop everything; the exit code."""
    own_file = opts.args.address_file is None
    path = opts.args.address_file or os.path.join(tempfile.mkdtemp(prefix="env-servers-"), "servers.txt")
    path = os.path.abspath(path)
    started = time.monotonic()
    ray = _start_ray(opts)
    signals.install()
    fleet = None
    try:
        fleet = Fleet(ray, _start_actors(ray, opts), path)
        deadline = started + opts.args.startup_timeout
        while not fleet.all_up():
            if signals.received is not None:
                return 128 + signals.received
            if time.monotonic() > deadline:
                down = [s.index for s in fleet.slots if s.address is None]
                raise LaunchError(
                    f"--startup-timeout: expected {opts.args.num_servers} servers listening within "
                    f"{opts.args.startup_timeout:g} s, got servers {down} still starting (too few CPUs in the "
                    f"cluster for --cpus-per-server {opts.args.cpus_per_server:g}?)"
                )
            fleet.poll(0.5)
        _log(f"{opts.args.num_servers} servers up in {time.monotonic() - started:.1f} s; addresses in {path}")
        if not opts.command:
            while signals.received is None:
                fleet.poll(0.5)
            return 0
        if opts.args.sweep_shards is not None:
            return _run_sweep(ray, fleet, opts, signals)
        command = [*opts.command, "--server", f"file:{path}"]
        try:
            child = subprocess.Popen(
                command, env={**os.environ, "ENV_SERVER_ADDRESS_FILE": path}, start_new_session=True
            )
        except OSError as exc:
            raise LaunchError(f"COMMAND: expected a program to run, got {command[0]!r} ({exc.strerror})") from None
        signals.child = child
        while child.poll() is None:
            fleet.poll(0.5)
        # A COMMAND killed by signal S (Popen's -S) exits the launcher the way a shell reports it: 128 + S.
        return 128 - child.returncode if child.returncode < 0 else child.returncode
    finally:
        if signals.child is not None and signals.child.poll() is None:
            signals.child.terminate()
            signals.child.wait()
        if fleet is not None:
            fleet.stop()
        ray.shutdown()
        if own_file:
            for p in (path, os.path.dirname(path)):
                try:
                    os.remove(p) if p == path else os.rmdir(p)
                except OSError:
                    pass


def _run_sweep(ray: Any, fleet: Fleet, opts: Options, signals: _Signals) -> int:
    """COMMAND's shards as Ray tasks against the fleet's servers, then their merge; the exit code."""
    count = opts.args.sweep_shards
    root = os.path.abspath(opts.args.sweep_dir)
    os.makedirs(root, exist_ok=True)
    command = sweep.absolute(opts.command)
    # The tasks run in Ray's workers, whose environment is the node's, not this launcher's.
    env = {k: os.environ[k] for k in ("RUST_LOG", "RUST_BACKTRACE") if k in os.environ}
    task = ray.remote(sweep.run_shard).options(
        num_cpus=opts.args.cpus_per_shard,
        max_retries=opts.args.shard_retries,
        retry_exceptions=False,  # an agent that fails is reported, not rerun: only a lost node is retried
        scheduling_strategy="SPREAD",
    )
    started = time.monotonic()
    pending = {task.remote(command, i, count, root, fleet.path, env): i for i in range(count)}
    failed: list[int] = []
    try:
        while pending:
            if signals.received is not None:
                return 128 + signals.received
            fleet.poll(0.5)
            ready, _ = ray.wait(list(pending), num_returns=len(pending), timeout=0)
            for ref in ready:
                index = pending.pop(ref)
                try:
                    result = ray.get(ref)
                except ray.exceptions.RayError as exc:
                    raise LaunchError(
                        f"shard {index}/{count}: expected it to finish within {opts.args.shard_retries} retries "
                        f"(--shard-retries), got {type(exc).__name__}: {exc}"
                    ) from None
                tries = result["attempts"]
                how = f"{len(tries)} attempts, resumed {sum(t['resume'] for t in tries)}x" if len(tries) > 1 else ""
                nodes = ", ".join(t["node"][:12] for t in tries)
                if result["code"] == 0:
                    _log(
                        f"shard {index}/{count} finished after {time.monotonic() - started:.1f} s on node {nodes} {how}"
                    )
                else:
                    _log(f"shard {index}/{count} failed with exit code {result['code']} (node {nodes})")
                    failed.append(result["code"])
        if failed:
            return failed[0]
    finally:
        for ref in pending:
            ray.cancel(ref, force=True)  # the agent dies with its worker (PR_SET_PDEATHSIG)
    folders = [sweep.shard_dir(root, i, count) for i in range(count)]
    report = sweep.report_argv(command, folders, os.path.join(root, "front"))
    _log(f"{count} shards finished in {time.monotonic() - started:.1f} s; merging into {report[-1]}")
    return subprocess.run(report, check=False).returncode


def main(argv: list[str] | None = None) -> int:
    opts = parse(sys.argv[1:] if argv is None else argv)
    signals = _Signals()
    try:
        return run(opts, signals)
    except LaunchError as exc:
        _log(str(exc))
        return 2
