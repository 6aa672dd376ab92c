"""Who may talk to the server: bearer tokens, TLS files, and the loopback rule.

Transport-free, like service.py: the fronts in server.py (grpc.aio, and the native
front, which checks tokens in Rust against the same `Tokens.entries`) take the
`authorization` metadata value and TLS material from here. A token's *name* is the
client's identity: service.py binds each session to the name that made it.

The token file's format, which the client reads too, is in shared.py.
"""

from __future__ import annotations

import dataclasses
import hmac
import ipaddress
import pathlib

from env_server.errors import Unauthenticated
from env_server.shared import SecurityConfigError, parse_token_lines

BEARER = "bearer "

# Messages of the two UNAUTHENTICATED answers; the native front (auth.rs) sends the same
# text. Neither quotes what the client sent: a near-miss token must not come back in logs.
MISSING_TOKEN = "expected metadata 'authorization: Bearer <token>', got no authorization metadata"
MALFORMED_TOKEN = "expected metadata 'authorization: Bearer <token>', got a value that does not start with 'Bearer '"
UNKNOWN_TOKEN = "the bearer token in 'authorization' matches none of this server's tokens (--auth-token-file)"


@dataclasses.dataclass(frozen=True)
class Tokens:
    """The bearer tokens a server accepts, each with the client name it stands for."""

    entries: tuple[tuple[str, str], ...]

    @classmethod
    def load(cls, path: str | pathlib.Path) -> Tokens:
        try:
            text = pathlib.Path(path).read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise SecurityConfigError(f"--auth-token-file: expected a readable UTF-8 file, got {path}: {exc}") from exc
        entries = parse_token_lines(text, str(path))
        if not entries:
            raise SecurityConfigError(f"--auth-token-file: expected at least one token line in {path}, got none")
        names = [name for name, _ in entries]
        tokens = [token for _, token in entries]
        duplicated = sorted({n for n in names if names.count(n) > 1})
        if duplicated:
            raise SecurityConfigError(f"--auth-token-file: expected unique names in {path}, got {duplicated} twice")
        if len(set(tokens)) != len(tokens):
            raise SecurityConfigError(f"--auth-token-file: expected every token once in {path}, got one twice")
        return cls(tuple(entries))

    def identify(self, authorization: str | None) -> str:
        """The client name of an `authorization` metadata value; Unauthenticated otherwise.

        Every token is compared, in constant time each, so the time taken does not say
        which token (or how much of one) matched.
        """
        if authorization is None:
            raise Unauthenticated(MISSING_TOKEN)
        if authorization[: len(BEARER)].lower() != BEARER:
            raise Unauthenticated(MALFORMED_TOKEN)
        offered = authorization[len(BEARER) :].strip().encode()
        found = None
        for name, token in self.entries:
            if hmac.compare_digest(offered, token.encode()):
                found = name
        if found is None:
            raise Unauthenticated(UNKNOWN_TOKEN)
        return found


@dataclasses.dataclass(frozen=True)
class ServerTls:
    """PEM bytes of the server's certificate chain and key, and of the CA that signs
    client certificates (set: mutual TLS, every client must present one)."""

    cert_chain: bytes
    private_key: bytes
    client_ca: bytes | None = None

    @classmethod
    def load(cls, cert: str | pathlib.Path, key: str | pathlib.Path, client_ca: str | pathlib.Path | None) -> ServerTls:
        return cls(
            _pem("--tls-cert", cert, "CERTIFICATE"),
            _pem("--tls-key", key, "PRIVATE KEY"),
            None if client_ca is None else _pem("--tls-client-ca", client_ca, "CERTIFICATE"),
        )


def _pem(flag: str, path: str | pathlib.Path, kind: str) -> bytes:
    """A PEM file's bytes, checked for a block of `kind` so a swapped file fails at startup."""
    try:
        data = pathlib.Path(path).read_bytes()
    except OSError as exc:
        raise SecurityConfigError(f"{flag}: expected a readable PEM file, got {path}: {exc}") from exc
    if f"{kind}-----".encode() not in data:
        raise SecurityConfigError(f"{flag}: expected a PEM file with a '{kind}' block, got {path} without one")
    return data


def is_loopback(host: str) -> bool:
    """Whether binding `host` exposes the server only to this machine."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False  # a host name other than localhost may resolve to anything


def check_exposure(host: str, tls: ServerTls | None, tokens: Tokens | None, insecure: bool) -> None:
    """Refuse a non-loopback bind without TLS and a token, unless `insecure` says so."""
    if insecure or is_loopback(host) or (tls is not None and tokens is not None):
        return
    missing = " and no ".join(
        what
        for what, absent in (
            ("TLS (--tls-cert, --tls-key)", tls is None),
            ("token (--auth-token-file)", tokens is None),
        )
        if absent
    )
    raise SecurityConfigError(
        f"--host: {host!r} is not a loopback address and the server has no {missing}: any client that "
        "reaches the port could read the traffic, make sessions, and step or close them. Expected "
        "--tls-cert, --tls-key and --auth-token-file (docs/env-server.md: 'Serving other hosts'), or --insecure to "
        "serve this way anyway on a network you trust"
    )
