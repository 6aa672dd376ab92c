"""The client's connection: a plain or TLS channel, the bearer token, the retry rule,
and the errors a failed call raises. `env_server.client` builds on it (and re-exports
the errors). TLS and tokens live here and in the fronts, never in the service (docs/design.md, "Boundaries").
"""

from __future__ import annotations

import dataclasses
import math
import os
import pathlib
import queue
import threading
import time
from collections.abc import Callable
from typing import Any

import grpc

from env_server._proto.mo_env.v1 import env_pb2_grpc
from env_server.shared import parse_token_lines


class RemoteError(Exception):
    """A failed call: `code` is the grpc.StatusCode, `message` the server's explanation."""

    def __init__(self, code: grpc.StatusCode, message: str) -> None:
        super().__init__(f"{code.name}: {message}")
        self.code = code
        self.message = message


class InvalidArgumentError(RemoteError, ValueError):
    """INVALID_ARGUMENT: the request (action, kwargs, indices) was malformed."""


class NotFoundError(RemoteError, LookupError):
    """NOT_FOUND: unknown env id or session."""


class FailedPreconditionError(RemoteError):
    """FAILED_PRECONDITION: e.g. Step before Reset."""


class PermissionDeniedError(RemoteError, PermissionError):
    """PERMISSION_DENIED: a file kwarg names a file outside the server's data directories."""


class ResourceExhaustedError(RemoteError):
    """RESOURCE_EXHAUSTED: session limit, instance limits (per session, live) or message size."""


class UnauthenticatedError(RemoteError, PermissionError):
    """UNAUTHENTICATED: the server takes bearer tokens and this client's is missing or unknown."""


class DeadlineExceededError(RemoteError, TimeoutError):
    """DEADLINE_EXCEEDED: no answer within the client's `timeout` (a stopped, overloaded or unreachable server)."""


DEFAULT_TIMEOUT_S = 60.0
"""How long a call waits for its answer unless `timeout=` says otherwise: the agent's
ceiling for a Make (docs/reliability.md, "Deadlines"), far above any one Step."""


_ERRORS = {
    grpc.StatusCode.INVALID_ARGUMENT: InvalidArgumentError,
    grpc.StatusCode.NOT_FOUND: NotFoundError,
    grpc.StatusCode.FAILED_PRECONDITION: FailedPreconditionError,
    grpc.StatusCode.PERMISSION_DENIED: PermissionDeniedError,
    grpc.StatusCode.RESOURCE_EXHAUSTED: ResourceExhaustedError,
    grpc.StatusCode.UNAUTHENTICATED: UnauthenticatedError,
    grpc.StatusCode.DEADLINE_EXCEEDED: DeadlineExceededError,
}


def _error(exc: grpc.RpcError) -> RemoteError:
    code = exc.code()
    return _ERRORS.get(code, RemoteError)(code, exc.details() or "")


def _no_answer(call: str, timeout: float) -> DeadlineExceededError:
    return DeadlineExceededError(
        grpc.StatusCode.DEADLINE_EXCEEDED, f"{call}: expected an answer within timeout={timeout:g} s, got none"
    )


def check_timeout(timeout: float | None) -> float | None:
    """`timeout=` as given, or a ValueError naming what was expected."""
    # inf too: grpc takes a deadline it cannot represent as one already past.
    if timeout is not None and not (isinstance(timeout, (int, float)) and 0 < timeout < math.inf):
        raise ValueError(f"timeout: expected finite seconds > 0 or None (wait forever), got {timeout!r}")
    return timeout


PathLike = str | os.PathLike[str]


def read_token_file(path: PathLike) -> str:
    """The one token line of a token file (`token` or `name:token`, as the server's
    --auth-token-file lines are)."""
    entries = parse_token_lines(pathlib.Path(path).read_text(encoding="utf-8"), str(path))
    if len(entries) != 1:
        raise ValueError(f"token_file: expected exactly one token line in {path}, got {len(entries)}")
    return entries[0][1]


@dataclasses.dataclass(frozen=True)
class Credentials:
    """How to reach a server that takes TLS or a bearer token: the client's TLS and token
    keywords (env_server.client's module doc), carried as one value to the channel."""

    tls_ca: PathLike | None = None
    tls_client_cert: PathLike | None = None
    tls_client_key: PathLike | None = None
    token: str | None = None
    token_file: PathLike | None = None


class Channel:
    """A channel (plain or TLS), its stub, the token, the retry rule (UNAVAILABLE only) and
    each call's deadline (`timeout` seconds; None waits forever)."""

    def __init__(
        self,
        address: str,
        max_message_mb: float = 64,
        retries: int = 5,
        *,
        credentials: Credentials = Credentials(),
        timeout: float | None = DEFAULT_TIMEOUT_S,
    ) -> None:
        self.timeout = check_timeout(timeout)
        c = credentials
        size = int(max_message_mb * 1024 * 1024)
        options = [("grpc.max_send_message_length", size), ("grpc.max_receive_message_length", size)]
        if (c.tls_client_cert is None) != (c.tls_client_key is None):
            raise ValueError("tls_client_cert, tls_client_key: expected both or neither, got one")
        if c.token is not None and c.token_file is not None:
            raise ValueError("token, token_file: expected at most one, got both")
        # http:// and https:// choose the transport; any other target (host:port,
        # unix:...) goes to grpc as it is.
        scheme, sep, target = address.partition("://")
        if not sep or scheme not in ("http", "https"):
            scheme, target = "", address
        implied = c.tls_ca is not None or c.tls_client_cert is not None
        if scheme == "http" and implied:
            raise ValueError(f"address: expected host:port or https://... with TLS files, got {address!r}")
        if scheme == "https" or (scheme == "" and implied):
            tls = grpc.ssl_channel_credentials(
                root_certificates=_read(c.tls_ca),
                private_key=_read(c.tls_client_key),
                certificate_chain=_read(c.tls_client_cert),
            )
            self.channel = grpc.secure_channel(target, tls, options=options)
        else:
            self.channel = grpc.insecure_channel(target, options=options)
        token = c.token if c.token_file is None else read_token_file(c.token_file)
        # Sent as call metadata rather than call credentials, which grpc allows only over
        # TLS: a token on a plaintext loopback connection is legitimate (no --tls-cert).
        self.metadata = () if token is None else (("authorization", f"Bearer {token}"),)
        self.stub = env_pb2_grpc.EnvServiceStub(self.channel)
        self.retries = retries

    def call(self, method: Callable[..., Any], request: Any) -> Any:
        delay = 0.05
        for attempt in range(self.retries + 1):
            try:
                return method(request, metadata=self.metadata, timeout=self.timeout)
            except grpc.RpcError as exc:
                if exc.code() == grpc.StatusCode.DEADLINE_EXCEEDED and self.timeout is not None:
                    raise _no_answer(type(request).__name__.removesuffix("Request"), self.timeout) from None
                if exc.code() != grpc.StatusCode.UNAVAILABLE or attempt == self.retries:
                    raise _error(exc) from None
            time.sleep(delay)
            delay = min(delay * 2, 2.0)
        raise AssertionError("unreachable")

    def open_stream(self, method: Callable[..., Any]) -> Stream:
        """A bidirectional stream on `method` (e.g. stub.StepStream), one response per request."""
        return Stream(method, self.metadata, self.timeout)

    def close(self) -> None:
        self.channel.close()


class Stream:
    """A bidirectional stream stepped in lockstep: `call` sends one request and waits for its
    response. Not retried, since a request sent may have been applied: after a failed call
    the stream is closed (`open` is False), and the caller opens a new one.

    grpc's deadline covers a whole stream, which lives for many steps; each call's own
    deadline is kept by a watchdog thread that cancels the stream when an answer is
    `timeout` seconds late (to within a tenth of it, at most 0.5 s); a call only notes
    its due time and clears it.
    """

    def __init__(
        self, method: Callable[..., Any], metadata: tuple[tuple[str, str], ...], timeout: float | None
    ) -> None:
        # grpc's sync API reads requests from an iterator on its own thread; a queue feeds it,
        # and None ends the iterator, which half-closes the stream.
        self._requests: queue.SimpleQueue[Any] = queue.SimpleQueue()
        self._responses = method(iter(self._requests.get, None), metadata=metadata)
        self.open = True
        self._timeout = timeout
        self._due: float | None = None  # when the call in flight must have its answer
        self._expired = False  # the watchdog cancelled the stream
        self._lock = threading.Lock()
        if timeout is not None:
            threading.Thread(target=self._watch, name="env_server stream deadline", daemon=True).start()

    def _watch(self) -> None:
        assert self._timeout is not None
        while self.open:
            time.sleep(min(0.5, self._timeout / 10))
            with self._lock:
                if self._due is not None and time.monotonic() > self._due:
                    self._expired = True
                    self._responses.cancel()
                    return

    def call(self, request: Any) -> Any:
        if not self.open:
            raise RuntimeError("this stream failed or was closed; open a new one")
        self._requests.put(request)
        if self._timeout is not None:
            self._due = time.monotonic() + self._timeout
        try:
            return next(self._responses)
        except grpc.RpcError as exc:
            self.close()
            if self._expired:
                raise _no_answer(type(request).__name__.removesuffix("Request"), self._timeout) from None
            raise _error(exc) from None
        except StopIteration:
            self.close()
            raise RemoteError(grpc.StatusCode.UNKNOWN, "the server ended the stream without answering") from None
        finally:
            with self._lock:
                self._due = None
                if self._expired:  # cancelled just as the answer came: the next call takes a new stream
                    self.close()

    def close(self) -> None:
        if self.open:
            self.open = False
            self._requests.put(None)


def _read(path: PathLike | None) -> bytes | None:
    return None if path is None else pathlib.Path(path).read_bytes()
