"""`python -m env_server`: serve the registry over gRPC, or `--list` it.

stdout carries exactly one line, `LISTENING <host>:<port>`, once the port is bound
(port 0 lets the OS choose); everything else is logged to stderr.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import os
import signal
import sys

from env_server.instances import DEFAULT_MAX_WORKERS
from env_server.registry import Registry, RegistryError
from env_server.security import SecurityConfigError, ServerTls, Tokens, check_exposure
from env_server.service import DEFAULT_KEEPALIVE_S, DEFAULT_MAX_ENVS_PER_SESSION, DEFAULT_MAX_LIVE_ENVS, FRONTS
from env_server.task import ClosedForm, Objective


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="env-server", description=__doc__.splitlines()[0])
    p.add_argument("--host", default="127.0.0.1", help="address to bind (default 127.0.0.1)")
    p.add_argument("--port", type=int, default=0, help="port to bind; 0 = chosen by the OS (default)")
    p.add_argument("--max-sessions", type=int, default=64, help="open sessions allowed at once (default 64)")
    p.add_argument("--max-message-mb", type=float, default=64, help="largest request/response in MiB (default 64)")
    p.add_argument(
        "--session-lease", type=float, default=120.0, help="seconds before an unused session is closed (default 120)"
    )
    p.add_argument(
        "--max-workers",
        type=int,
        default=DEFAULT_MAX_WORKERS,
        help="worker processes one session may ask for (MakeRequest.num_workers; default: one per CPU)",
    )
    p.add_argument(
        "--max-envs-per-session",
        type=int,
        default=DEFAULT_MAX_ENVS_PER_SESSION,
        help="instances one session may hold (MakeRequest.num_envs); more is RESOURCE_EXHAUSTED "
        f"(default {DEFAULT_MAX_ENVS_PER_SESSION})",
    )
    p.add_argument(
        "--max-live-envs",
        type=int,
        default=DEFAULT_MAX_LIVE_ENVS,
        help="instances all open sessions may hold together; a Make past it is RESOURCE_EXHAUSTED "
        f"(default {DEFAULT_MAX_LIVE_ENVS})",
    )
    p.add_argument(
        "--data-dir",
        action="append",
        default=[],
        metavar="DIR",
        help="a directory whose files clients may name in file kwargs (xml_file, clip_path, ...); "
        "repeatable. The shipped assets are always allowed; any other path is PERMISSION_DENIED",
    )
    p.add_argument(
        "--front",
        choices=FRONTS,
        default="auto",
        help="gRPC transport: native (the Rust env_server_native extension), grpcio (grpc.aio), "
        "or auto = native when installed (default)",
    )
    p.add_argument(
        "--busy-poll-us",
        type=int,
        default=0,
        help="native front: microseconds a StepStream waits for its next request without sleeping; "
        "spends that much CPU per Step to cut B=1 latency on machines slow to wake (default 0: off)",
    )
    p.add_argument(
        "--keepalive-seconds",
        type=float,
        default=DEFAULT_KEEPALIVE_S,
        help="seconds of silence after which the server pings a connection, and waits as long for the answer "
        "before dropping it: a client gone without closing its connection (a half-open one) is let go, and "
        f"its streams' sessions with it (default {DEFAULT_KEEPALIVE_S:g})",
    )
    p.add_argument("--tls-cert", help="PEM certificate chain: serve TLS (with --tls-key)")
    p.add_argument("--tls-key", help="PEM private key of --tls-cert")
    p.add_argument(
        "--tls-client-ca", help="PEM CA certificate(s): mutual TLS, every client must present a certificate it signed"
    )
    p.add_argument(
        "--auth-token-file",
        help="file of bearer tokens, one per line, optionally name:token; every EnvService call must carry "
        "'authorization: Bearer <token>' and sessions answer only the token that made them",
    )
    p.add_argument(
        "--insecure",
        action="store_true",
        help="allow a non-loopback --host without TLS and a token (only on a network you trust)",
    )
    p.add_argument("--list", action="store_true", help="print every env id with its objectives and exit")
    p.add_argument("--log-level", default="INFO", help="logging level for stderr (default INFO)")
    return p


def _fmt_objective(o: Objective) -> str:
    closed = "" if o.closed_form is ClosedForm.NONE else f", closed_form = {o.closed_form.value}"
    return f"    {o.name}: {o.description} [{o.min:g}, {o.max:g}]{closed}"


def print_list(registry: Registry, out=sys.stdout) -> None:
    """Every env id (shipped, entry points, adapter patterns) with description and objectives;
    an entry point that did not load shows "unavailable: <why>" instead."""
    for entry in registry.entries():
        print(f"{entry.env_id}  {registry.listed_description(entry)}", file=out)
        for o in entry.objectives:
            print(_fmt_objective(o), file=out)
    for prefix in registry.prefixes:
        print(f"{prefix.pattern}  {prefix.task_class.description}", file=out)
        if prefix.task_class.objectives:
            for o in prefix.task_class.objectives:
                print(_fmt_objective(o), file=out)
        else:
            print("    objectives depend on the env (see its spec)", file=out)


def _security(args: argparse.Namespace) -> tuple[ServerTls | None, Tokens | None]:
    """The TLS material and tokens the flags name; refuses an exposed bind without them."""
    if (args.tls_cert is None) != (args.tls_key is None):
        raise SecurityConfigError(
            f"--tls-cert and --tls-key: expected both or neither, got only {'--tls-cert' if args.tls_cert else '--tls-key'}"
        )
    if args.tls_client_ca is not None and args.tls_cert is None:
        raise SecurityConfigError(
            "--tls-client-ca: expected with --tls-cert and --tls-key (mutual TLS is TLS), got alone"
        )
    tls = None if args.tls_cert is None else ServerTls.load(args.tls_cert, args.tls_key, args.tls_client_ca)
    tokens = None if args.auth_token_file is None else Tokens.load(args.auth_token_file)
    check_exposure(args.host, tls, tokens, args.insecure)
    return tls, tokens


def _check_flags(args: argparse.Namespace) -> str | None:
    """What is wrong with the numeric flags and --data-dir, or None."""
    if (
        args.max_sessions < 1
        or args.max_message_mb <= 0
        or args.session_lease <= 0
        or args.max_workers < 0
        or args.max_envs_per_session < 1
        or args.max_live_envs < 1
        or not args.keepalive_seconds > 0
    ):
        return (
            "expected --max-sessions >= 1, --max-message-mb > 0, --session-lease > 0, "
            "--max-workers >= 0, --max-envs-per-session >= 1, --max-live-envs >= 1, --keepalive-seconds > 0; got "
            f"{args.max_sessions}, {args.max_message_mb}, {args.session_lease}, {args.max_workers}, "
            f"{args.max_envs_per_session}, {args.max_live_envs}, {args.keepalive_seconds}"
        )
    missing = [d for d in args.data_dir if not os.path.isdir(d)]
    if missing:
        return f"--data-dir: expected existing directories, got {missing}"
    return None


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    logging.basicConfig(
        stream=sys.stderr, level=args.log_level.upper(), format="%(asctime)s %(levelname)s %(name)s: %(message)s"
    )
    try:
        registry = Registry()
    except RegistryError as exc:
        print(f"env-server: {exc}", file=sys.stderr)
        return 2
    if args.list:
        print_list(registry)
        return 0
    problem = _check_flags(args)
    if problem is not None:
        print(f"env-server: {problem}", file=sys.stderr)
        return 2

    try:
        tls, tokens = _security(args)
    except SecurityConfigError as exc:
        print(f"env-server: {exc}", file=sys.stderr)
        return 2

    from env_server.server import resolve_front  # grpc is only needed when serving

    try:
        front = resolve_front(args.front)
    except ValueError as exc:
        print(f"env-server: --{exc}", file=sys.stderr)
        return 2
    if args.busy_poll_us < 0 or (args.busy_poll_us > 0 and front != "native"):
        print(
            f"env-server: --busy-poll-us: expected 0, or > 0 with the native front; got {args.busy_poll_us} "
            f"with the {front} front",
            file=sys.stderr,
        )
        return 2
    asyncio.run(_serve(args, registry, front, tls, tokens))
    return 0


async def _serve(
    args: argparse.Namespace, registry: Registry, front: str, tls: ServerTls | None, tokens: Tokens | None
) -> None:
    """Serve until SIGTERM or SIGINT."""
    from env_server.server import serve

    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(sig, stop.set)
    await serve(
        registry,
        host=args.host,
        port=args.port,
        max_sessions=args.max_sessions,
        max_message_bytes=int(args.max_message_mb * 1024 * 1024),
        lease_seconds=args.session_lease,
        max_workers=args.max_workers,
        max_envs_per_session=args.max_envs_per_session,
        max_live_envs=args.max_live_envs,
        data_dirs=tuple(args.data_dir),
        front=front,
        busy_poll_us=args.busy_poll_us,
        keepalive_seconds=args.keepalive_seconds,
        tls=tls,
        tokens=tokens,
        insecure=args.insecure,
        stop=stop,
    )


if __name__ == "__main__":
    sys.exit(main())
