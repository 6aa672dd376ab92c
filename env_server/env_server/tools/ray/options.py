"""`python -m env_server.tools.ray --num-servers N [options] [-- COMMAND ...]`: the launcher's command line.

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
import math
import os
import shlex
from dataclasses import dataclass

from env_server.tools.ray import sweep

NAMESPACE = "env_server"
"""The Ray namespace of the server actors (named NAME-0 .. NAME-(N-1), --name)."""


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
        "--ray-start-timeout",
        type=float,
        default=60.0,
        metavar="S",
        help="seconds `ray.init` may take to start a local Ray (or connect to --address) before the launcher "
        "gives up; a local Ray that fails or takes longer is killed and started again, 3 times in all "
        "(default 60; it takes 5-6 s on two busy cores)",
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
    for flag, value in (("--startup-timeout", args.startup_timeout), ("--ray-start-timeout", args.ray_start_timeout)):
        if not 0 < value < math.inf:  # also refuses nan
            parser.error(f"{flag}: expected finite seconds > 0, got {value:g}")
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


def ray_address(flag: str | None) -> str:
    """The address for `ray.init`: the flag, else $RAY_ADDRESS, else "local" (start one here)."""
    if flag is not None:
        return flag
    return os.environ.get("RAY_ADDRESS") or "local"
