"""The gRPC front end: the only server module that imports grpc.

Everything here is plumbing: requests to Session calls, results to messages (built by
wire.py), and one exception -> status mapping (`_to_status`). All RPCs run on one
asyncio event loop; Step and StepStream run inline (no thread hop) because that is the
latency-critical path, while Make runs Task constructors in a worker thread so a slow
simulator load does not stall other sessions.
"""

from __future__ import annotations

import asyncio
import functools
import json
import logging
import time
from typing import Any, AsyncIterator, Awaitable, Callable

import grpc
from grpc_health.v1 import health, health_pb2, health_pb2_grpc

import env_server
from env_server import wire
from env_server._proto.mo_env.v1 import env_pb2 as pb
from env_server._proto.mo_env.v1 import env_pb2_grpc
from env_server.errors import EnvServerError, InvalidArgument, NotFound, ResourceExhausted
from env_server.instances import DEFAULT_MAX_WORKERS
from env_server.registry import Registry
from env_server.session import Autoreset, Session, make_session

log = logging.getLogger(__name__)

PROTOCOL_VERSION = "1.0.0"
SERVICE_NAME = "mo_env.v1.EnvService"
CAPABILITIES = (
    "step_stream",
    "autoreset.same_step",
    "autoreset.next_step",
    "autoreset.disabled",
    "dict_observations",
    "info_keys",
    "episode_returns",
    "instance_workers",
)

_AUTORESET = {
    pb.AUTORESET_MODE_UNSPECIFIED: Autoreset.SAME_STEP,
    pb.AUTORESET_MODE_SAME_STEP: Autoreset.SAME_STEP,
    pb.AUTORESET_MODE_NEXT_STEP: Autoreset.NEXT_STEP,
    pb.AUTORESET_MODE_DISABLED: Autoreset.DISABLED,
}


# ---------------------------------------------------------------------- errors
def _to_status(exc: BaseException) -> tuple[grpc.StatusCode, str]:
    """The one place where exceptions become gRPC statuses."""
    if isinstance(exc, EnvServerError):
        return grpc.StatusCode[exc.code], exc.message
    log.error("unexpected server error", exc_info=exc)
    return grpc.StatusCode.INTERNAL, f"env_server bug: {type(exc).__name__}: {exc}"


def _rpc(method: Callable[..., Awaitable[Any]]) -> Callable[..., Awaitable[Any]]:
    """Turn any exception escaping a unary handler into its status."""

    @functools.wraps(method)
    async def wrapper(self: "EnvService", request: Any, context: grpc.aio.ServicerContext) -> Any:
        try:
            return await method(self, request, context)
        except Exception as exc:
            code, message = _to_status(exc)
            await context.abort(code, message)

    return wrapper


# ---------------------------------------------------------------------- service
class EnvService(env_pb2_grpc.EnvServiceServicer):
    """mo_env.v1.EnvService over a Registry and a table of leased Sessions."""

    def __init__(
        self, registry: Registry, *, max_sessions: int, max_message_bytes: int, lease_seconds: float, max_workers: int
    ) -> None:
        self.registry = registry
        self.max_sessions = max_sessions
        self.max_workers = max_workers
        self.max_message_bytes = max_message_bytes
        self.lease_seconds = lease_seconds
        self.sessions: dict[str, Session] = {}
        self._encoders: dict[str, wire.StepEncoder] = {}  # per session, for its Step responses
        self._making = 0  # Make calls between the limit check and registration

    # -------------------------------------------------------------- sessions
    def _session(self, session_id: str) -> Session:
        session = self.sessions.get(session_id)
        if session is None:
            raise NotFound(f"unknown session '{session_id}' (closed, expired, or never made)")
        return session

    def close_session(self, session_id: str, reason: str) -> None:
        session = self.sessions.pop(session_id, None)
        self._encoders.pop(session_id, None)
        if session is not None:
            session.close()
            log.info("closed session %s (%s): %s; %d open", session_id, session.env_id, reason, len(self.sessions))

    def close_all(self) -> None:
        for session_id in list(self.sessions):
            self.close_session(session_id, "server shutdown")

    async def reap(self) -> None:
        """Close sessions idle for longer than the lease, forever (cancel to stop)."""
        period = min(1.0, self.lease_seconds / 4)
        while True:
            await asyncio.sleep(period)
            deadline = time.monotonic() - self.lease_seconds
            for session_id, session in list(self.sessions.items()):
                if session.last_used < deadline:
                    self.close_session(session_id, f"lease of {self.lease_seconds:g} s expired")

    # -------------------------------------------------------------- RPCs
    @_rpc
    async def GetVersion(self, request: pb.GetVersionRequest, context: Any) -> pb.GetVersionResponse:
        return pb.GetVersionResponse(
            protocol_version=PROTOCOL_VERSION,
            server_version=env_server.__version__,
            capabilities=CAPABILITIES,
            max_message_bytes=self.max_message_bytes,
        )

    @_rpc
    async def ListEnvs(self, request: pb.ListEnvsRequest, context: Any) -> pb.ListEnvsResponse:
        return pb.ListEnvsResponse(
            envs=[
                pb.EnvInfo(env_id=e.env_id, description=e.description, objectives=wire.objectives_pb(e.objectives))
                for e in self.registry.entries()
            ]
        )

    @_rpc
    async def Make(self, request: pb.MakeRequest, context: Any) -> pb.MakeResponse:
        if request.num_envs < 1:
            raise InvalidArgument(f"num_envs: expected >= 1, got {request.num_envs}")
        if request.num_workers > self.max_workers:
            raise InvalidArgument(
                f"num_workers: expected at most {self.max_workers} (this server's --max-workers), "
                f"got {request.num_workers}"
            )
        kwargs = _parse_kwargs(request.kwargs_json)
        autoreset = _AUTORESET.get(request.autoreset_mode)
        if autoreset is None:
            raise InvalidArgument(f"autoreset_mode: expected one of {sorted(_AUTORESET)}, got {request.autoreset_mode}")
        open_now = len(self.sessions) + self._making
        if open_now >= self.max_sessions:
            raise ResourceExhausted(
                f"session limit {self.max_sessions} reached ({open_now} open); close sessions or start "
                "the server with --max-sessions"
            )
        self._making += 1
        try:
            loop = asyncio.get_running_loop()
            build = functools.partial(
                self._build,
                request.env_id,
                request.num_envs,
                kwargs,
                seed=request.seed if request.HasField("seed") else None,
                autoreset=autoreset,
                discount=request.discount if request.HasField("discount") else None,
                info_keys=tuple(request.info_keys),
                num_workers=request.num_workers,
            )
            future = loop.run_in_executor(None, build)
            try:
                session = await asyncio.shield(future)
            except asyncio.CancelledError:
                future.add_done_callback(_close_orphan)
                raise
        finally:
            self._making -= 1
        self.sessions[session.id] = session
        self._encoders[session.id] = wire.StepEncoder(session.leaves, session.num_envs, len(session.objectives))
        log.info(
            "made session %s: %s x%d; %d open", session.id, session.env_id, session.num_envs, len(self.sessions)
        )
        return pb.MakeResponse(session_id=session.id, spec=wire.spec_pb(session), lease_seconds=self.lease_seconds)

    def _build(self, env_id: str, num_envs: int, kwargs: dict[str, Any], **options: Any) -> Session:
        return make_session(self.registry.resolve(env_id), num_envs, kwargs, **options)

    @_rpc
    async def Reset(self, request: pb.ResetRequest, context: Any) -> pb.ResetResponse:
        session = self._session(request.session_id)
        return wire.reset_pb(session.reset(request.env_indices, request.seeds))

    async def Step(self, request: pb.StepRequest, context: grpc.aio.ServicerContext) -> bytes:
        try:
            return self._step(request)
        except Exception as exc:
            code, message = _to_status(exc)
            await context.abort(code, message)

    def _step(self, request: pb.StepRequest) -> bytes:
        """One Step, as a serialized StepResponse (see _method_handlers)."""
        session = self.sessions.get(request.session_id)
        if session is None:
            self._session(request.session_id)
        action = request.action
        dtype = wire.PB_TO_DTYPE.get(action.dtype) or pb.DType.Name(action.dtype)
        return self._encoders[session.id].encode(session.step(dtype, action.shape, action.data))

    async def StepStream(
        self, request_iterator: AsyncIterator[pb.StepRequest], context: grpc.aio.ServicerContext
    ) -> AsyncIterator[bytes]:
        """A stream owns the sessions it steps: when it ends they are closed.

        grpc.aio cannot tell a client's half-close from a cancelled or dropped stream
        (both can surface as the end of the request iterator, and context.cancelled()
        stays False), so every end closes them, except an error status for a bad
        request, which leaves the sessions usable (the lease reaps them if the client
        is gone too).
        """
        stepped: set[str] = set()
        aborted = False
        try:
            async for request in request_iterator:
                try:
                    response = self._step(request)
                except Exception as exc:
                    aborted = True
                    code, message = _to_status(exc)
                    await context.abort(code, message)
                stepped.add(request.session_id)
                yield response
        finally:
            if not aborted:
                self._close_stream_sessions(stepped)

    def _close_stream_sessions(self, session_ids: set[str]) -> None:
        for session_id in session_ids:
            self.close_session(session_id, "its StepStream broke (client went away)")

    @_rpc
    async def Close(self, request: pb.CloseRequest, context: Any) -> pb.CloseResponse:
        self._session(request.session_id)
        self.close_session(request.session_id, "closed by the client")
        return pb.CloseResponse()


def _close_orphan(future: asyncio.Future) -> None:
    """A Make whose client went away while its Tasks were being built."""
    if not future.cancelled() and future.exception() is None:
        future.result().close()


def _parse_kwargs(kwargs_json: str) -> dict[str, Any]:
    if not kwargs_json:
        return {}
    try:
        kwargs = json.loads(kwargs_json)
    except json.JSONDecodeError as exc:
        raise InvalidArgument(f"kwargs_json: expected a JSON object, got invalid JSON {kwargs_json!r}: {exc}") from exc
    if not isinstance(kwargs, dict):
        raise InvalidArgument(f"kwargs_json: expected a JSON object, got {type(kwargs).__name__} {kwargs_json!r}")
    return kwargs


# ---------------------------------------------------------------------- serving
# Step and StepStream return wire.StepEncoder bytes: building and then serializing a
# StepResponse per Step cost more than the rest of the server's per-Step work.
_ENCODED_RESPONSES = ("Step", "StepStream")
_HANDLER_KINDS = {  # (client streaming, server streaming) -> handler factory
    (False, False): grpc.unary_unary_rpc_method_handler,
    (False, True): grpc.unary_stream_rpc_method_handler,
    (True, False): grpc.stream_unary_rpc_method_handler,
    (True, True): grpc.stream_stream_rpc_method_handler,
}


def _method_handlers(service: EnvService) -> dict[str, grpc.RpcMethodHandler]:
    """What env_pb2_grpc.add_EnvServiceServicer_to_server registers, except _ENCODED_RESPONSES."""
    handlers = {}
    for method in pb.DESCRIPTOR.services_by_name["EnvService"].methods:
        request = getattr(pb, method.input_type.name)
        response = getattr(pb, method.output_type.name)
        handlers[method.name] = _HANDLER_KINDS[method.client_streaming, method.server_streaming](
            getattr(service, method.name),
            request_deserializer=request.FromString,
            response_serializer=None if method.name in _ENCODED_RESPONSES else response.SerializeToString,
        )
    return handlers


def _bind_address(host: str, port: int) -> str:
    return f"[{host}]:{port}" if ":" in host and not host.startswith("[") else f"{host}:{port}"


async def serve(
    registry: Registry,
    *,
    host: str = "127.0.0.1",
    port: int = 0,
    max_sessions: int = 64,
    max_message_bytes: int = 64 * 1024 * 1024,
    lease_seconds: float = 120.0,
    max_workers: int = DEFAULT_MAX_WORKERS,
    stop: asyncio.Event | None = None,
) -> None:
    """Serve until `stop` is set; prints `LISTENING <host>:<port>` once bound."""
    service = EnvService(
        registry,
        max_sessions=max_sessions,
        max_message_bytes=max_message_bytes,
        lease_seconds=lease_seconds,
        max_workers=max_workers,
    )
    server = grpc.aio.server(
        options=[
            ("grpc.max_receive_message_length", max_message_bytes),
            ("grpc.max_send_message_length", max_message_bytes),
        ]
    )
    handlers = _method_handlers(service)
    server.add_generic_rpc_handlers((grpc.method_handlers_generic_handler(SERVICE_NAME, handlers),))
    server.add_registered_method_handlers(SERVICE_NAME, handlers)
    health_servicer = health.aio.HealthServicer()
    health_pb2_grpc.add_HealthServicer_to_server(health_servicer, server)
    bound = server.add_insecure_port(_bind_address(host, port))
    if bound == 0:
        raise OSError(f"could not bind {_bind_address(host, port)}")
    await server.start()
    for name in ("", SERVICE_NAME):
        await health_servicer.set(name, health_pb2.HealthCheckResponse.SERVING)
    print(f"LISTENING {_bind_address(host, bound)}", flush=True)
    log.info(
        "serving %s on %s (max sessions %d, max message %d bytes, lease %g s, max workers %d)",
        SERVICE_NAME, _bind_address(host, bound), max_sessions, max_message_bytes, lease_seconds, max_workers,
    )
    reaper = asyncio.create_task(service.reap())
    stop = stop or asyncio.Event()
    try:
        await stop.wait()
    finally:
        log.info("shutting down")
        reaper.cancel()
        await health_servicer.enter_graceful_shutdown()
        await server.stop(grace=1.0)
        service.close_all()
