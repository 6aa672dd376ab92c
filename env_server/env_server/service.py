"""mo_env.v1.EnvService without a transport: the RPCs over a Registry and the Sessions.

Both fronts in server.py serve this one object: grpc.aio, and the native (tonic)
front of env_server_native, so the two cannot drift apart. Requests and responses are
the generated protobuf messages; errors are EnvServerError subclasses, mapped to a
status code name in exactly one place (`status_of`).

Owners: with bearer tokens (security.py), a front passes the client name of the
call's token as `owner`; a session answers only its maker, and anyone else gets the
same NOT_FOUND as for an id that never existed. NOT_FOUND rather than PERMISSION_DENIED:
session ids are random, so a different answer would only tell a prober which ids are
live. Without tokens every owner is None and every client sees every session.

Threads: unary RPCs and the lease reaper run on the asyncio loop. Step may run on the
native front's own thread, so everything that reads or changes the session table, or
steps or resets a Session, holds `_lock` (uncontended under grpc.aio, which runs
everything on the loop).
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import dataclasses
import functools
import json
import logging
import sys
import threading
import time
from collections.abc import Sequence
from typing import Any, Protocol

from google.protobuf.message import DecodeError

import env_server
from env_server import render, wire
from env_server._proto.mo_env.v1 import env_pb2 as pb
from env_server.construction import make_session
from env_server.datafiles import DataDirs
from env_server.errors import ConstructorError, EnvServerError, InvalidArgument, NotFound, ResourceExhausted, quote
from env_server.memory import release_memory
from env_server.registry import Registry
from env_server.session import Autoreset, Session, check_seed_range

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
    "close_session",
    "render",
    "reward_scale",
)
# The transports server.py can serve this service through (`--front`).
FRONTS = ("auto", "native", "grpcio")
# Seconds of silence before a front pings a connection, and for its answer before it drops
# the connection (--keepalive-seconds): a client gone without a FIN or RST (its host died,
# a partition) would otherwise hold its connection, and the sessions of its StepStreams,
# until their lease runs out; the connection itself, forever.
DEFAULT_KEEPALIVE_S = 30.0
# Unary RPCs answered on the asyncio loop (Step is answered inline by `step`).
UNARY_METHODS = ("GetVersion", "ListEnvs", "Make", "Reset", "CloseSession", "Close", "Render")
# Instances one session may hold, and all sessions together (--max-envs-per-session,
# --max-live-envs). A humanoid-run instance costs about 1.5 MiB and a millisecond or
# more to build, so 4096 stays within a few GiB and Make's reply within seconds.
DEFAULT_MAX_ENVS_PER_SESSION = 1024
DEFAULT_MAX_LIVE_ENVS = 4096
# Seconds from a Close to the memory release it asks for (Closes in between share it).
RELEASE_DELAY_S = 0.2
# Request and response message classes of every EnvService method, read once from the proto.
MESSAGE_TYPES = {
    m.name: (getattr(pb, m.input_type.name), getattr(pb, m.output_type.name))
    for m in pb.DESCRIPTOR.services_by_name["EnvService"].methods
}

_AUTORESET = {
    pb.AUTORESET_MODE_UNSPECIFIED: Autoreset.SAME_STEP,
    pb.AUTORESET_MODE_SAME_STEP: Autoreset.SAME_STEP,
    pb.AUTORESET_MODE_NEXT_STEP: Autoreset.NEXT_STEP,
    pb.AUTORESET_MODE_DISABLED: Autoreset.DISABLED,
}


def decode_request(method: str, data: bytes) -> Any:
    """`data` as `method`'s request message; bytes that do not parse are the client's error."""
    request_type = MESSAGE_TYPES[method][0]
    try:
        return request_type.FromString(data)
    except DecodeError as exc:
        raise InvalidArgument(
            f"{method}: expected a serialized {request_type.DESCRIPTOR.full_name}, got {len(data)} bytes "
            f"that do not parse as one ({quote(str(exc), 200)})"
        ) from exc


def status_of(exc: BaseException) -> tuple[str, str]:
    """The one place where exceptions become statuses: (grpc.StatusCode name, message)."""
    if isinstance(exc, EnvServerError):
        return exc.code, exc.message
    log.error("unexpected server error", exc_info=exc)
    return "INTERNAL", f"env_server bug: {type(exc).__name__}: {exc}"


class Reply(Protocol):
    """How a front receives the answer to a submitted unary call (env_server_native.Reply)."""

    def ok(self, response: bytes) -> None: ...

    def error(self, code_name: str, message: str) -> None: ...


@dataclasses.dataclass
class Lease:
    """An open session and what the service keeps beside it."""

    session: Session
    encoder: wire.StepEncoder  # writes its Step responses
    owner: str | None  # the client name that made it (None without tokens)


class EnvService:
    """mo_env.v1.EnvService over a Registry and a table of leased Sessions."""

    def __init__(
        self,
        registry: Registry,
        *,
        max_sessions: int,
        max_message_bytes: int,
        lease_seconds: float,
        max_workers: int,
        loop: asyncio.AbstractEventLoop,
        max_envs_per_session: int = DEFAULT_MAX_ENVS_PER_SESSION,
        max_live_envs: int = DEFAULT_MAX_LIVE_ENVS,
        data_dirs: DataDirs | None = None,
    ) -> None:
        self.registry = registry
        self.max_sessions = max_sessions
        self.max_envs_per_session = max_envs_per_session
        self.max_live_envs = max_live_envs
        self.data_dirs = data_dirs or DataDirs()
        self.max_workers = max_workers
        self.max_message_bytes = max_message_bytes
        self.lease_seconds = lease_seconds
        self.loop = loop
        self.leases: dict[str, Lease] = {}  # by session id
        self._making = 0  # Make calls between the limit check and registration
        self._making_envs = 0  # the instances those calls are building
        self._release_pending = False
        self._lock = threading.Lock()

    # The exception -> status mapping, also where the native front looks for it.
    status_of = staticmethod(status_of)

    # -------------------------------------------------------------- sessions
    def _lease(self, session_id: str, owner: str | None) -> Lease:
        lease = self.leases.get(session_id)
        if lease is None or lease.owner != owner:
            raise NotFound(f"unknown session '{session_id}' (closed, expired, or never made)")
        return lease

    def _session(self, session_id: str, owner: str | None) -> Session:
        return self._lease(session_id, owner).session

    def close_session(self, session_id: str, reason: str) -> None:
        with self._lock:
            lease = self.leases.pop(session_id, None)
            if lease is not None:
                lease.session.close()
        if lease is None:
            return
        env_id = lease.session.env_id
        del lease  # the last reference: release_memory can only return what is freed
        self._release_soon()
        log.info("closed session %s (%s): %s; %d open", session_id, env_id, reason, len(self.leases))

    def _release_soon(self) -> None:
        """release_memory on the loop shortly, once for a burst of Closes (close_all, the
        sessions of a broken stream): its full cycle collection holds the GIL for 0.1-0.3 s
        with a few humanoid sessions open on the 2-core machine."""
        with self._lock:
            if self._release_pending:
                return
            self._release_pending = True
        try:
            self.loop.call_soon_threadsafe(self.loop.call_later, RELEASE_DELAY_S, self._release)
        except RuntimeError:  # the loop is closed: the process is exiting
            pass

    def _release(self) -> None:
        with self._lock:
            self._release_pending = False
        release_memory()

    def close_all(self) -> None:
        for session_id in list(self.leases):
            self.close_session(session_id, "server shutdown")

    async def reap(self) -> None:
        """Close sessions idle for longer than the lease, forever (cancel to stop)."""
        period = min(1.0, self.lease_seconds / 4)
        while True:
            await asyncio.sleep(period)
            deadline = time.monotonic() - self.lease_seconds
            # No Session in this frame across the sleep: a loop variable left holding the
            # last one kept a closed session's simulators alive until the next sweep.
            expired = [sid for sid, lease in list(self.leases.items()) if lease.session.last_used < deadline]
            for session_id in expired:
                self.close_session(session_id, f"lease of {self.lease_seconds:g} s expired")

    # -------------------------------------------------------------- unary RPCs
    # Every unary RPC takes the caller's client name (None without tokens); see "Owners".
    async def GetVersion(self, request: pb.GetVersionRequest, owner: str | None = None) -> pb.GetVersionResponse:
        return pb.GetVersionResponse(
            protocol_version=PROTOCOL_VERSION,
            server_version=env_server.__version__,
            capabilities=CAPABILITIES,
            max_message_bytes=self.max_message_bytes,
        )

    async def ListEnvs(self, request: pb.ListEnvsRequest, owner: str | None = None) -> pb.ListEnvsResponse:
        return pb.ListEnvsResponse(
            envs=[
                pb.EnvInfo(
                    env_id=e.env_id,
                    description=self.registry.listed_description(e),
                    objectives=wire.objectives_pb(e.objectives),
                )
                for e in self.registry.entries()
            ]
        )

    def _live_envs(self) -> int:
        """Instances in open sessions and in Makes still building."""
        with self._lock:  # the native front's thread may close sessions meanwhile
            return self._making_envs + sum(lease.session.num_envs for lease in self.leases.values())

    def _check_limits(self, num_envs: int) -> None:
        """The server-wide limits: open sessions and live instances."""
        open_now = len(self.leases) + self._making
        if open_now >= self.max_sessions:
            raise ResourceExhausted(
                f"session limit {self.max_sessions} reached ({open_now} open); close sessions or start "
                "the server with --max-sessions"
            )
        live = self._live_envs()
        if live + num_envs > self.max_live_envs:
            raise ResourceExhausted(
                f"num_envs: {num_envs} more instances would pass this server's limit of {self.max_live_envs} "
                f"live instances across all sessions (--max-live-envs; {live} live now); close sessions or ask for fewer"
            )

    async def Make(self, request: pb.MakeRequest, owner: str | None = None) -> pb.MakeResponse:
        if request.num_envs < 1:
            raise InvalidArgument(f"num_envs: expected >= 1, got {request.num_envs}")
        if request.num_envs > self.max_envs_per_session:
            raise ResourceExhausted(
                f"num_envs: this server allows at most {self.max_envs_per_session} instances per session "
                f"(--max-envs-per-session), got {request.num_envs}"
            )
        if request.num_workers > self.max_workers:
            raise InvalidArgument(
                f"num_workers: expected at most {self.max_workers} (this server's --max-workers), "
                f"got {request.num_workers}"
            )
        kwargs = self.data_dirs.resolve_kwargs(_parse_kwargs(request.kwargs_json))
        if request.HasField("seed"):
            check_seed_range("seed", [request.seed, request.seed + request.num_envs - 1])
        autoreset = _AUTORESET.get(request.autoreset_mode)
        if autoreset is None:
            raise InvalidArgument(f"autoreset_mode: expected one of {sorted(_AUTORESET)}, got {request.autoreset_mode}")
        self._check_limits(request.num_envs)
        self._making += 1
        self._making_envs += request.num_envs
        cancel = threading.Event()
        try:
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
                cancel=cancel,
            )
            # Task constructors can take seconds (MJCF compiles, worker spawns): off the loop.
            future = self.loop.run_in_executor(None, build)
            try:
                session = await asyncio.shield(future)
            except asyncio.CancelledError:
                # The client went away (deadline, cancel; the native front's dropped call
                # cancels this coroutine too): stop building and close what was built.
                cancel.set()
                future.add_done_callback(_close_orphan)
                raise
        finally:
            self._making -= 1
            self._making_envs -= request.num_envs
        encoder = wire.StepEncoder(session.leaves, session.num_envs, len(session.objectives))
        with self._lock:
            self.leases[session.id] = Lease(session, encoder, owner)
        log.info(
            "made session %s: %s x%d%s; %d open",
            session.id,
            session.env_id,
            session.num_envs,
            "" if owner is None else f" for client {owner!r}",
            len(self.leases),
        )
        return pb.MakeResponse(session_id=session.id, spec=wire.spec_pb(session), lease_seconds=self.lease_seconds)

    def _build(self, env_id: str, num_envs: int, kwargs: dict[str, Any], **options: Any) -> Session:
        entry = self.registry.resolve(env_id)
        try:
            session = make_session(entry, num_envs, kwargs, **options)
        except ConstructorError as exc:
            self.registry.note_make(entry, exc)
            raise
        self.registry.note_make(entry, None)
        return session

    async def Reset(self, request: pb.ResetRequest, owner: str | None = None) -> pb.ResetResponse:
        with self._lock:
            session = self._session(request.session_id, owner)
            return wire.reset_pb(session.reset(request.env_indices, request.seeds))

    async def CloseSession(self, request: pb.CloseRequest, owner: str | None = None) -> pb.CloseResponse:
        with self._lock:
            self._session(request.session_id, owner)
        self.close_session(request.session_id, "closed by the client")
        return pb.CloseResponse()

    # The deprecated name of CloseSession (gRPC's JavaScript library hides the channel's
    # own close() behind an RPC named Close); still served for older clients.
    Close = CloseSession

    async def Render(self, request: pb.RenderRequest, owner: str | None = None) -> pb.RenderResponse:
        # On the loop, like Reset: OpenGL contexts belong to the thread that made them.
        with self._lock:
            session = self._session(request.session_id, owner)
            indices = session.render_indices(request.env_indices)
            size = render.frame_size(request.width, request.height, len(indices), self.max_message_bytes)
            frames = session.render(indices, size.width, size.height, request.camera)
            return pb.RenderResponse(frames=wire.tensor(frames), cameras=session.cameras, fps=session.render_fps)

    def submit(self, method: str, request: bytes, reply: Reply, owner: str | None = None) -> concurrent.futures.Future:
        """Answer the serialized unary `request` of client `owner` on the loop, from any
        thread, via `reply`.

        Cancelling the returned future cancels the call (its client went away).
        """
        return asyncio.run_coroutine_threadsafe(self._answer(method, request, reply, owner), self.loop)

    async def _answer(self, method: str, request: bytes, reply: Reply, owner: str | None) -> None:
        try:
            response = await getattr(self, method)(decode_request(method, request), owner)
        except Exception as exc:
            reply.error(*status_of(exc))
            return
        reply.ok(response.SerializeToString())

    # -------------------------------------------------------------- Step
    def step(self, session_id: str, dtype: int, shape: Sequence[int], data: bytes, owner: str | None = None) -> bytes:
        """One Step of client `owner`, as a serialized StepResponse (wire.StepEncoder's bytes)."""
        with self._lock:
            lease = self.leases.get(session_id)
            if lease is None or lease.owner != owner:
                lease = self._lease(session_id, owner)
            return lease.encoder.encode(lease.session.step(_dtype_name(dtype), shape, data))

    def open_stream(self) -> StreamSteps:
        return StreamSteps(self)


class StreamSteps:
    """One StepStream: it owns the sessions it steps, and closes them when it ends.

    A front calls `finish(aborted)` exactly once. Every end of the stream closes its
    sessions (a client's half-close, a cancelled or dropped stream: grpc.aio cannot tell
    these apart), except a bad request's error status (`aborted=True`), which leaves the
    sessions usable; the lease reaps them if the client is gone too.
    """

    def __init__(self, service: EnvService) -> None:
        self._service = service
        self._stepped: set[str] = set()

    def step(self, session_id: str, dtype: int, shape: Sequence[int], data: bytes, owner: str | None = None) -> bytes:
        response = self._service.step(session_id, dtype, shape, data, owner)
        self._stepped.add(session_id)
        return response

    def finish(self, aborted: bool) -> None:
        if not aborted:
            for session_id in self._stepped:
                self._service.close_session(session_id, "its StepStream broke (client went away)")
        self._stepped.clear()


def _close_orphan(future: asyncio.Future) -> None:
    """A Make whose client went away while its Tasks were being built."""
    if not future.cancelled() and future.exception() is None:
        future.result().close()


def _dtype_name(dtype: int) -> str:
    """The action tensor's dtype name; a number that is no DType value is the client's error."""
    name = wire.PB_TO_DTYPE.get(dtype)
    if name is not None:
        return name
    if dtype in pb.DType.values():
        return pb.DType.Name(dtype)
    raise InvalidArgument(f"action.dtype: expected a mo_env.v1.DType value {sorted(pb.DType.values())}, got {dtype}")


def _parse_kwargs(kwargs_json: str) -> dict[str, Any]:
    if not kwargs_json:
        return {}
    try:
        kwargs = json.loads(kwargs_json)
    except json.JSONDecodeError as exc:
        raise InvalidArgument(
            f"kwargs_json: expected a JSON object, got invalid JSON {quote(kwargs_json)}: {exc}"
        ) from exc
    except RecursionError as exc:
        raise InvalidArgument(
            f"kwargs_json: expected a JSON object nested at most about {sys.getrecursionlimit()} deep, got {quote(kwargs_json)}"
        ) from exc
    if not isinstance(kwargs, dict):
        raise InvalidArgument(f"kwargs_json: expected a JSON object, got {type(kwargs).__name__} {quote(kwargs_json)}")
    return kwargs
