"""`python -m env_server.tools.healthcheck`: ask a server's grpc.health.v1 service whether it is SERVING.

Exit status 0 when it answers SERVING, 1 otherwise (with the reason on stderr), so it can be a
container probe (`deploy/k8s`) or a Docker HEALTHCHECK. Kubernetes' built-in `grpc:` probe
cannot speak TLS, and a server bound to a non-loopback address serves TLS (docs/env-server.md, "Serving
other hosts"); this check does, with the CA that signed the server and the name its
certificate carries. The health service needs no bearer token.

    python -m env_server.tools.healthcheck --port 50051 --tls-ca /etc/env-server/tls/ca.crt --server-name env-server
"""

from __future__ import annotations

import argparse
import pathlib
import sys

import grpc
from grpc_health.v1 import health_pb2, health_pb2_grpc


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m env_server.tools.healthcheck", description=__doc__.splitlines()[0])
    p.add_argument("--host", default="127.0.0.1", help="server address (default 127.0.0.1)")
    p.add_argument("--port", type=int, required=True, help="server port")
    p.add_argument("--service", default="", help="service name to ask about (default '': the whole server)")
    p.add_argument("--timeout", type=float, default=3.0, help="seconds before giving up (default 3)")
    p.add_argument("--tls-ca", help="PEM CA certificate that signed the server's: connect with TLS")
    p.add_argument(
        "--server-name",
        help="name to verify the server's certificate against (default: --host); with --tls-ca",
    )
    p.add_argument("--tls-client-cert", help="PEM client certificate, for a server with --tls-client-ca")
    p.add_argument("--tls-client-key", help="PEM private key of --tls-client-cert")
    return p


def check(args: argparse.Namespace) -> str | None:
    """None when the server answers SERVING, else why not."""
    target = f"{args.host}:{args.port}"
    if args.tls_ca is None:
        channel = grpc.insecure_channel(target)
    else:
        client_pair = (None, None)
        if args.tls_client_cert is not None:
            client_pair = (
                pathlib.Path(args.tls_client_key).read_bytes(),
                pathlib.Path(args.tls_client_cert).read_bytes(),
            )
        credentials = grpc.ssl_channel_credentials(pathlib.Path(args.tls_ca).read_bytes(), *client_pair)
        options = [] if args.server_name is None else [("grpc.ssl_target_name_override", args.server_name)]
        channel = grpc.secure_channel(target, credentials, options=options)
    with channel:
        try:
            response = health_pb2_grpc.HealthStub(channel).Check(
                health_pb2.HealthCheckRequest(service=args.service), timeout=args.timeout
            )
        except grpc.RpcError as exc:
            return f"{target}: {exc.code().name}: {exc.details()}"
    if response.status != health_pb2.HealthCheckResponse.SERVING:
        return f"{target}: {health_pb2.HealthCheckResponse.ServingStatus.Name(response.status)}"
    return None


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    if (args.tls_client_cert is None) != (args.tls_client_key is None):
        print("healthcheck: --tls-client-cert and --tls-client-key: expected both or neither", file=sys.stderr)
        return 2
    if args.tls_ca is None and (args.server_name is not None or args.tls_client_cert is not None):
        print("healthcheck: --server-name and --tls-client-cert: expected with --tls-ca", file=sys.stderr)
        return 2
    try:
        problem = check(args)
    except OSError as exc:
        problem = f"reading TLS files: {exc}"
    if problem is not None:
        print(f"healthcheck: not serving: {problem}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
