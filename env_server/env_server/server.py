"""The gRPC fronts: the only server module that touches gRPC.

`service.EnvService` answers every RPC; a front only carries messages and statuses.
Two fronts serve it, chosen by `--front`:

- `native` (env_server_native, a Rust extension built by scripts/setup.sh): tonic on
  its own thread in this process. The thread that reads a StepRequest off the socket
  runs the Step itself, so a streamed Step crosses no thread inside the server (the
  B=1 figures are in docs/benchmarks/index.md). Other RPCs go to the asyncio loop.
- `grpcio` (grpc.aio, pure Python): every message travels from grpc core's I/O thread
  through a poller thread to the asyncio loop, 0.15-0.3 ms more per B=1 Step on the
  2-vCPU bench machine.

`auto` (the default) is native when the extension is installed, else grpcio.

Both fronts serve TLS (optionally mutual) and check bearer tokens (security.py) on
every EnvService call; grpc.health.v1 answers without a token, so a load balancer or
orchestrator can probe the server. The caller's client name goes to the service,
which binds sessions to it.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import AsyncIterator, Awaitable, Callable
from typing import Any

import grpc
from grpc_health.v1 import health, health_pb2, health_pb2_grpc

from env_server import gl
from env_server._proto.mo_env.v1 import env_pb2 as pb
from env_server.datafiles import DataDirs
from env_server.errors import EnvServerError
from env_server.instances import DEFAULT_MAX_WORKERS
from env_server.registry import Registry
from env_server.security import ServerTls, Tokens, check_exposure
from env_server.service import (
    DEFAULT_KEEPALIVE_S,
    DEFAULT_MAX_ENVS_PER_SESSION,
    DEFAULT_MAX_LIVE_ENVS,
    FRONTS,
    MESSAGE_TYPES,
    SERVICE_NAME,
    UNARY_METHODS,
    EnvService,
    decode_request,
    status_of,
)

log = logging.getLogger(__name__)


# ---------------------------------------------------------------------- grpc.aio front
class _Undecodable:
    """What the request deserializer hands a handler for bytes that do not parse.

    grpc.aio answers a deserializer's own exception with UNKNOWN before any handler
    runs; carried to the handler, the error becomes the client's INVALID_ARGUMENT.
    """

    def __init__(self, error: EnvServerError) -> None:
        self.error = error


def _deserializer(method: str) -> Callable[[bytes], Any]:
    def deserialize(data: bytes) -> Any:
        try:
            return decode_request(method, data)
        except EnvServerError as exc:
            return _Undecodable(exc)

    return deserialize


def _parsed(request: Any) -> Any:
    """The request message; raises the decode error of an _Undecodable one."""
    if isinstance(request, _Undecodable):
        raise request.error
    return request


def _owner(tokens: Tokens | None, context: grpc.aio.ServicerContext) -> str | None:
    """The caller's client name (None without tokens); raises Unauthenticated."""
    if tokens is None:
        return None
    authorization = next((v for k, v in context.invocation_metadata() or () if k == "authorization"), None)
    return tokens.identify(authorization)


def _unary(method: Callable[[Any, str | None], Awaitable[Any]], tokens: Tokens | None) -> Callable[..., Awaitable[Any]]:
    """A grpc.aio handler for a unary service method: exceptions become its status."""

    async def handler(request: Any, context: grpc.aio.ServicerContext) -> Any:
        try:
            return await method(_parsed(request), _owner(tokens, context))
        except Exception as exc:
            code, message = status_of(exc)
            await context.abort(grpc.StatusCode[code], message)

    return handler


class _GrpcAioHandlers:
    """The grpc.aio handlers of Step and StepStream over one EnvService."""

    def __init__(self, service: EnvService, tokens: Tokens | None) -> None:
        self.service = service
        self.tokens = tokens

    async def Step(self, request: pb.StepRequest, context: grpc.aio.ServicerContext) -> bytes:
        try:
            request = _parsed(request)
            action = request.action
            owner = _owner(self.tokens, context)
            return self.service.step(request.session_id, action.dtype, action.shape, action.data, owner)
        except Exception as exc:
            code, message = status_of(exc)
            await context.abort(grpc.StatusCode[code], message)

    async def StepStream(
        self, request_iterator: AsyncIterator[pb.StepRequest], context: grpc.aio.ServicerContext
    ) -> AsyncIterator[bytes]:
        try:
            owner = _owner(self.tokens, context)
        except Exception as exc:
            code, message = status_of(exc)
            await context.abort(grpc.StatusCode[code], message)
        steps = self.service.open_stream()
        aborted = False
        try:
            async for request in request_iterator:
                try:
                    request = _parsed(request)
                    action = request.action
                    response = steps.step(request.session_id, action.dtype, action.shape, action.data, owner)
                except Exception as exc:
                    aborted = True
                    code, message = status_of(exc)
                    await context.abort(grpc.StatusCode[code], message)
                yield response
        finally:
            steps.finish(aborted)


# Step and StepStream return wire.StepEncoder bytes: building and then serializing a
# StepResponse per Step cost more than the rest of the server's per-Step work.
_ENCODED_RESPONSES = ("Step", "StepStream")
_HANDLER_KINDS = {  # (client streaming, server streaming) -> handler factory
    (False, False): grpc.unary_unary_rpc_method_handler,
    (False, True): grpc.unary_stream_rpc_method_handler,
    (True, False): grpc.stream_unary_rpc_method_handler,
    (True, True): grpc.stream_stream_rpc_method_handler,
}


def _method_handlers(service: EnvService, tokens: Tokens | None) -> dict[str, grpc.RpcMethodHandler]:
    """What env_pb2_grpc.add_EnvServiceServicer_to_server registers, except _ENCODED_RESPONSES."""
    streaming = _GrpcAioHandlers(service, tokens)
    handlers = {}
    for method in pb.DESCRIPTOR.services_by_name["EnvService"].methods:
        _, response = MESSAGE_TYPES[method.name]
        if method.name in UNARY_METHODS:
            behaviour = _unary(getattr(service, method.name), tokens)
        else:
            behaviour = getattr(streaming, method.name)
        handlers[method.name] = _HANDLER_KINDS[method.client_streaming, method.server_streaming](
            behaviour,
            request_deserializer=_deserializer(method.name),
            response_serializer=None if method.name in _ENCODED_RESPONSES else response.SerializeToString,
        )
    return handlers


def _bind_address(host: str, port: int) -> str:
    return f"[{host}]:{port}" if ":" in host and not host.startswith("[") else f"{host}:{port}"


class _GrpcAioFront:
    """grpc.aio serving the service, plus grpc.health.v1."""

    def __init__(
        self,
        service: EnvService,
        host: str,
        port: int,
        max_message_bytes: int,
        busy_poll_us: int,
        keepalive_seconds: float,
        tls: ServerTls | None,
        tokens: Tokens | None,
    ) -> None:
        if busy_poll_us:
            raise ValueError(
                f"busy_poll_us: expected 0 with the grpcio front (only the native front polls), got {busy_poll_us}"
            )
        keepalive_ms = int(keepalive_seconds * 1000)
        self.server = grpc.aio.server(
            options=[
                ("grpc.max_receive_message_length", max_message_bytes),
                ("grpc.max_send_message_length", max_message_bytes),
                # Pings after keepalive_seconds of silence, also without calls in flight and
                # without data in between, and drops a connection whose ping is not answered
                # as long, so that a half-open connection is let go. grpc core waits for the
                # answer ping_timeout_ms (default 1 min), not keepalive_timeout_ms alone.
                ("grpc.keepalive_time_ms", keepalive_ms),
                ("grpc.keepalive_timeout_ms", keepalive_ms),
                ("grpc.keepalive_permit_without_calls", 1),
                ("grpc.http2.max_pings_without_data", 0),
                ("grpc.http2.ping_timeout_ms", keepalive_ms),
            ]
        )
        handlers = _method_handlers(service, tokens)
        self.server.add_generic_rpc_handlers((grpc.method_handlers_generic_handler(SERVICE_NAME, handlers),))
        self.server.add_registered_method_handlers(SERVICE_NAME, handlers)
        self.health = health.aio.HealthServicer()
        health_pb2_grpc.add_HealthServicer_to_server(self.health, self.server)
        if tls is None:
            self.port = self.server.add_insecure_port(_bind_address(host, port))
        else:
            credentials = grpc.ssl_server_credentials(
                [(tls.private_key, tls.cert_chain)],
                root_certificates=tls.client_ca,
                require_client_auth=tls.client_ca is not None,
            )
            self.port = self.server.add_secure_port(_bind_address(host, port), credentials)
        if self.port == 0:
            raise OSError(f"could not bind {_bind_address(host, port)}")

    async def start(self) -> None:
        await self.server.start()
        for name in ("", SERVICE_NAME):
            await self.health.set(name, health_pb2.HealthCheckResponse.SERVING)

    async def stop(self, grace: float) -> None:
        await self.health.enter_graceful_shutdown()
        await self.server.stop(grace=grace)


class _NativeFront:
    """env_server_native.NativeFront (tonic on its own thread), which has its own health service."""

    def __init__(
        self,
        service: EnvService,
        host: str,
        port: int,
        max_message_bytes: int,
        busy_poll_us: int,
        keepalive_seconds: float,
        tls: ServerTls | None,
        tokens: Tokens | None,
    ) -> None:
        import env_server_native

        self.front = env_server_native.NativeFront(
            service,
            host,
            port,
            max_message_bytes,
            busy_poll_us,
            keepalive_seconds=keepalive_seconds,
            tls=None if tls is None else (tls.cert_chain, tls.private_key, tls.client_ca),
            tokens=None if tokens is None else list(tokens.entries),
        )
        self.port = self.front.port

    async def start(self) -> None:
        pass  # serving since construction

    async def stop(self, grace: float) -> None:
        # stop() joins the front thread, whose in-flight unary calls may need this loop.
        await asyncio.get_running_loop().run_in_executor(None, self.front.stop, grace)


def native_front_available() -> bool:
    """Whether the env_server_native extension is installed (scripts/setup.sh builds it)."""
    try:
        import env_server_native  # noqa: F401
    except ImportError:
        return False
    return True


def resolve_front(front: str) -> str:
    """`front` as served: "native" or "grpcio" ("auto" is native when installed)."""
    if front not in FRONTS:
        raise ValueError(f"front: expected one of {FRONTS}, got {front!r}")
    if front == "auto":
        return "native" if native_front_available() else "grpcio"
    if front == "native" and not native_front_available():
        raise ValueError(
            "front: 'native' needs the env_server_native extension, which is not installed "
            "(scripts/setup.sh builds it); use 'grpcio' or 'auto'"
        )
    return front


_FRONT_CLASSES = {"native": _NativeFront, "grpcio": _GrpcAioFront}


async def serve(
    registry: Registry,
    *,
    host: str = "127.0.0.1",
    port: int = 0,
    max_sessions: int = 64,
    max_message_bytes: int = 64 * 1024 * 1024,
    lease_seconds: float = 120.0,
    max_workers: int = DEFAULT_MAX_WORKERS,
    max_envs_per_session: int = DEFAULT_MAX_ENVS_PER_SESSION,
    max_live_envs: int = DEFAULT_MAX_LIVE_ENVS,
    data_dirs: tuple[str, ...] = (),
    front: str = "auto",
    busy_poll_us: int = 0,
    keepalive_seconds: float = DEFAULT_KEEPALIVE_S,
    tls: ServerTls | None = None,
    tokens: Tokens | None = None,
    insecure: bool = False,
    stop: asyncio.Event | None = None,
) -> None:
    """Serve until `stop` is set; prints `LISTENING <host>:<port>` once bound.

    `busy_poll_us` (native front only): how long a StepStream waits for its next request
    without sleeping; it trades that much CPU per Step for B=1 latency (see docs/env-server.md, "Fronts").
    `keepalive_seconds`: silence after which a connection is pinged, and the wait for the
    answer before it is dropped (service.DEFAULT_KEEPALIVE_S).
    `tls` and `tokens` secure the EnvService; a non-loopback `host` needs both unless
    `insecure` (security.check_exposure raises SecurityConfigError).
    """
    check_exposure(host, tls, tokens, insecure)
    front = resolve_front(front)
    service = EnvService(
        registry,
        max_sessions=max_sessions,
        max_message_bytes=max_message_bytes,
        lease_seconds=lease_seconds,
        max_workers=max_workers,
        loop=asyncio.get_running_loop(),
        max_envs_per_session=max_envs_per_session,
        max_live_envs=max_live_envs,
        data_dirs=DataDirs(data_dirs),
    )
    running = _FRONT_CLASSES[front](
        service, host, port, max_message_bytes, busy_poll_us, keepalive_seconds, tls, tokens
    )
    await running.start()
    print(f"LISTENING {_bind_address(host, running.port)}", flush=True)
    log.info(
        "serving %s on %s through the %s front, %s, %s (max sessions %d, max message %d bytes, lease %g s, "
        "keepalive %g s, max workers %d, max instances %d per session and %d live, data directories %s, "
        "MuJoCo rendering through MUJOCO_GL=%s)",
        SERVICE_NAME,
        _bind_address(host, running.port),
        front,
        "plaintext" if tls is None else "mutual TLS" if tls.client_ca is not None else "TLS",
        "no tokens" if tokens is None else f"{len(tokens.entries)} bearer token(s)",
        max_sessions,
        max_message_bytes,
        lease_seconds,
        keepalive_seconds,
        max_workers,
        max_envs_per_session,
        max_live_envs,
        list(service.data_dirs.roots),
        gl.backend(),
    )
    reaper = asyncio.create_task(service.reap())
    stop = stop or asyncio.Event()
    try:
        await stop.wait()
    finally:
        log.info("shutting down")
        reaper.cancel()
        await running.stop(grace=1.0)
        service.close_all()
