"""`python -m env_server.tools.ray --num-servers N [options] [-- COMMAND ...]`: env servers on a Ray cluster.

The launcher's run: connect to (or start) Ray, start the server actors and wait for
them (fleet.py), then run COMMAND, or COMMAND's sweep shards as Ray tasks (sweep.py),
or wait for a signal; stop everything; exit with COMMAND's code. The flags and what
they do are in options.py.
"""

from __future__ import annotations

import faulthandler
import ipaddress
import logging
import os
import signal
import subprocess
import sys
import tempfile
import time
from typing import Any

from env_server.tools.ray import sweep, watchdog
from env_server.tools.ray.fleet import Fleet, LaunchError, log
from env_server.tools.ray.options import NAMESPACE, Options, parse, ray_address

_LOOPBACK_ENV = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"

STOP_TIMEOUT_S = 60.0
"""How long COMMAND may take to exit after SIGTERM, and the servers and Ray to stop."""


def _is_loopback(address: str) -> bool:
    host = address.rsplit(":", 1)[0].strip("[]")
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


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
    _init(ray, address, kwargs, opts.args.ray_start_timeout)
    return ray


def _init(ray: Any, address: str, kwargs: dict[str, Any], timeout: float) -> None:
    """`ray.init`, bounded: a local Ray that fails or hangs is started again (watchdog.py)."""
    local = address == "local"
    attempt = watchdog.attempt()
    started = time.monotonic()
    log(f"starting a local Ray with {kwargs['num_cpus']} CPUs" if local else f"connecting to Ray at {address}")

    def stuck() -> None:
        what = "a local Ray up" if local else f"to connect to Ray at {address}"
        why = f"--ray-start-timeout: expected {what} within {timeout:g} s, got no answer"
        if local:
            watchdog.restart_or_exit(log, why)
        log(why)
        os._exit(2)

    with watchdog.Deadline(timeout, stuck):
        try:
            ray.init(address=address, **kwargs)
        except Exception as exc:
            if not local:
                raise LaunchError(f"--address: expected a Ray cluster at {address}, got {type(exc).__name__}: {exc}")
            watchdog.restart_or_exit(log, f"the local Ray failed to start: {type(exc).__name__}: {exc}")
    os.environ.pop(watchdog.ATTEMPT_ENV, None)  # COMMAND and the servers start afresh
    again = f" (attempt {attempt})" if attempt > 1 else ""
    log(f"Ray {'up' if local else 'connected'} in {time.monotonic() - started:.1f} s{again}")


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
    code = 2  # what main reports if a LaunchError (or a crash) ends the run early
    try:
        fleet = Fleet(ray, _start_actors(ray, opts), path)
        code = _serve(ray, fleet, opts, signals, started)
        return code
    finally:
        _stop(ray, fleet, signals, code)
        if own_file:
            _remove(path)


def _serve(ray: Any, fleet: Fleet, opts: Options, signals: _Signals, started: float) -> int:
    """Wait for every server, then run COMMAND (its shards, or nothing until a signal); the exit code."""
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
    log(f"{opts.args.num_servers} servers up in {time.monotonic() - started:.1f} s; addresses in {fleet.path}")
    if not opts.command:
        while signals.received is None:
            fleet.poll(0.5)
        return 0
    if opts.args.sweep_shards is not None:
        return _run_sweep(ray, fleet, opts, signals)
    command = [*opts.command, "--server", f"file:{fleet.path}"]
    try:
        child = subprocess.Popen(
            command, env={**os.environ, "ENV_SERVER_ADDRESS_FILE": fleet.path}, start_new_session=True
        )
    except OSError as exc:
        raise LaunchError(f"COMMAND: expected a program to run, got {command[0]!r} ({exc.strerror})") from None
    signals.child = child
    while child.poll() is None:
        fleet.poll(0.5)
    # A COMMAND killed by signal S (Popen's -S) exits the launcher the way a shell reports it: 128 + S.
    return 128 - child.returncode if child.returncode < 0 else child.returncode


def _stop(ray: Any, fleet: Fleet | None, signals: _Signals, code: int) -> None:
    """Stop COMMAND (if it still runs), the servers and Ray, each within STOP_TIMEOUT_S.

    COMMAND gets SIGTERM and the time to write its checkpoint; `ray.shutdown` takes no
    timeout, so a Ray that does not stop gets its processes killed and the launcher
    exits with `code` anyway rather than wait for it.
    """
    child = signals.child
    if child is not None and child.poll() is None:
        child.terminate()
        try:
            child.wait(STOP_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            log(f"COMMAND (pid {child.pid}) still running {STOP_TIMEOUT_S:g} s after SIGTERM; killing it")
            child.kill()
            child.wait()

    def stuck() -> None:
        killed = watchdog.kill_descendants()
        log(f"Ray did not stop within {STOP_TIMEOUT_S:g} s; {killed} processes left killed, exiting with code {code}")
        os._exit(code)

    with watchdog.Deadline(STOP_TIMEOUT_S, stuck):
        if fleet is not None:
            fleet.stop()
        ray.shutdown()


def _remove(path: str) -> None:
    """The launcher's own address file and its temporary folder."""
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
                    log(
                        f"shard {index}/{count} finished after {time.monotonic() - started:.1f} s on node {nodes} {how}"
                    )
                else:
                    log(f"shard {index}/{count} failed with exit code {result['code']} (node {nodes})")
                    failed.append(result["code"])
        if failed:
            return failed[0]
    finally:
        for ref in pending:
            ray.cancel(ref, force=True)  # the agent dies with its worker (PR_SET_PDEATHSIG)
    folders = [sweep.shard_dir(root, i, count) for i in range(count)]
    report = sweep.report_argv(command, folders, os.path.join(root, "front"))
    log(f"{count} shards finished in {time.monotonic() - started:.1f} s; merging into {report[-1]}")
    return subprocess.run(report, check=False).returncode


def main(argv: list[str] | None = None) -> int:
    opts = parse(sys.argv[1:] if argv is None else argv)
    # `kill -USR1 PID` prints every thread's stack: where a launcher that seems stuck waits.
    faulthandler.register(signal.SIGUSR1, all_threads=True)
    signals = _Signals()
    try:
        return run(opts, signals)
    except LaunchError as exc:
        log(str(exc))
        return 2
