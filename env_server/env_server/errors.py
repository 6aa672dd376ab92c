"""Typed errors raised by sessions, the registry and validation.

Nothing below server.py knows about gRPC; each class here names the status code it
becomes, and service.status_of maps them in exactly one place for both fronts. Every message says which
field was wrong, what was expected and what arrived.
"""

from __future__ import annotations

from typing import Any

QUOTE_LIMIT = 64
"""Characters of a client's value that an error message quotes (gRPC carries the message
in trailing metadata, which clients cap at 8-16 KiB, so a message that echoed a
megabyte of input would be replaced by a RESOURCE_EXHAUSTED of its own)."""


def quote(value: Any, limit: int = QUOTE_LIMIT) -> str:
    """repr(value) for an error message: at most `limit` characters, with the full length
    said when cut."""
    text = repr(value)
    if len(text) <= limit:
        return text
    return f"{text[:limit]}... ({len(text)} characters)"


class EnvServerError(Exception):
    """Base class; `code` is the name of the gRPC status code this error becomes."""

    code: str = "INTERNAL"

    def __init__(self, message: str) -> None:
        super().__init__(message)
        self.message = message


class InvalidArgument(EnvServerError):
    """The request is malformed: bad action shape/dtype/value, bad kwargs, bad index."""

    code = "INVALID_ARGUMENT"


class NotFound(EnvServerError):
    """Unknown env id or session id."""

    code = "NOT_FOUND"


class FailedPrecondition(EnvServerError):
    """The request is well formed but the session is not in a state to serve it."""

    code = "FAILED_PRECONDITION"


class PermissionDenied(EnvServerError):
    """The request names something this server does not let clients reach (a file outside
    the operator's data directories). The message never says whether it exists."""

    code = "PERMISSION_DENIED"


class ResourceExhausted(EnvServerError):
    """A server limit (open sessions, instances per session, live instances) is reached."""

    code = "RESOURCE_EXHAUSTED"


class Cancelled(EnvServerError):
    """The client went away (deadline or cancel) while its call was still being answered."""

    code = "CANCELLED"


class Internal(EnvServerError):
    """A bug in a Task or in the server; the server keeps serving other sessions."""

    code = "INTERNAL"


class SimulatorError(Internal):
    """A Task raised while stepping or resetting; names env, session and instance."""


class ConstructorError(SimulatorError):
    """A Task's constructor raised for a reason that is not the caller's kwargs (a bug in
    the env or its install); `reason` is "<ExceptionType>: <message>"."""

    def __init__(self, message: str, reason: str) -> None:
        super().__init__(message)
        self.reason = reason


class Unauthenticated(EnvServerError):
    """The call carries no bearer token, or one this server does not know."""

    code = "UNAUTHENTICATED"
