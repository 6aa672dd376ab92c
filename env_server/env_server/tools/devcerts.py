"""Throwaway TLS material and tokens, for tests and for trying TLS out (the example in docs/scaling-out.md).

    python -m env_server.tools.devcerts --out certs --host 127.0.0.1 --host localhost --client learner

writes into `certs/`: `ca.pem` (a fresh CA) and `ca.key`, `server.pem` / `server.key` (valid
for every --host, as DNS name or IP address), `client.pem` / `client.key` (a client
certificate for mutual TLS), `tokens` (the server's --auth-token-file, one
`name:token` line per --client) and `<client>.token` (that client's line, for
`--token-file` / `token_file=`). Keys and tokens are written owner-readable only.

The CA lives for 30 days and its key sits next to it: this is for tests and trials.
For real hosts, use your organisation's CA (or a CA kept offline) and keep each key on
the machine that uses it. Needs the `cryptography` package (in requirements.lock).
"""

from __future__ import annotations

import argparse
import datetime
import ipaddress
import os
import pathlib
import secrets
import sys
from collections.abc import Sequence

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

LIFETIME = datetime.timedelta(days=30)


def _name(common_name: str) -> x509.Name:
    return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, common_name)])


def _builder(subject: str, issuer: x509.Name, public_key: ec.EllipticCurvePublicKey) -> x509.CertificateBuilder:
    now = datetime.datetime.now(datetime.timezone.utc)
    return (
        x509.CertificateBuilder()
        .subject_name(_name(subject))
        .issuer_name(issuer)
        .public_key(public_key)
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(now + LIFETIME)
    )


class Authority:
    """A CA that signs server and client certificates (ECDSA P-256)."""

    def __init__(self, common_name: str = "env_server test CA") -> None:
        self.key = ec.generate_private_key(ec.SECP256R1())
        self.cert = (
            _builder(common_name, _name(common_name), self.key.public_key())
            .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
            .add_extension(
                x509.KeyUsage(
                    digital_signature=True,
                    content_commitment=False,
                    key_encipherment=False,
                    data_encipherment=False,
                    key_agreement=False,
                    key_cert_sign=True,
                    crl_sign=True,
                    encipher_only=False,
                    decipher_only=False,
                ),
                critical=True,
            )
            .sign(self.key, hashes.SHA256())
        )

    def issue(self, common_name: str, hosts: Sequence[str] = (), client: bool = False) -> tuple[bytes, bytes]:
        """(certificate PEM, private key PEM) for a server valid for `hosts`, or a client."""
        key = ec.generate_private_key(ec.SECP256R1())
        usage = ExtendedKeyUsageOID.CLIENT_AUTH if client else ExtendedKeyUsageOID.SERVER_AUTH
        builder = (
            _builder(common_name, self.cert.subject, key.public_key())
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(x509.ExtendedKeyUsage([usage]), critical=False)
        )
        if hosts:
            builder = builder.add_extension(x509.SubjectAlternativeName([_san(h) for h in hosts]), critical=False)
        cert = builder.sign(self.key, hashes.SHA256())
        return cert.public_bytes(serialization.Encoding.PEM), _key_pem(key)

    @property
    def cert_pem(self) -> bytes:
        return self.cert.public_bytes(serialization.Encoding.PEM)

    @property
    def key_pem(self) -> bytes:
        return _key_pem(self.key)


def _key_pem(key: ec.EllipticCurvePrivateKey) -> bytes:
    return key.private_bytes(
        serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
    )


def _san(host: str) -> x509.GeneralName:
    try:
        return x509.IPAddress(ipaddress.ip_address(host))
    except ValueError:
        return x509.DNSName(host)


def new_token() -> str:
    """A random bearer token (43 URL-safe characters)."""
    return secrets.token_urlsafe(32)


def _write(path: pathlib.Path, data: bytes, secret: bool) -> None:
    # Secrets are created owner-only from the start, never readable in between.
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600 if secret else 0o644)
    with os.fdopen(fd, "wb") as f:
        f.write(data)


def write_all(out: pathlib.Path, hosts: Sequence[str], clients: Sequence[str]) -> dict[str, pathlib.Path]:
    """Write everything the module doc lists into `out`; returns the paths by file name."""
    out.mkdir(parents=True, exist_ok=True)
    ca = Authority()
    server_cert, server_key = ca.issue("env_server", hosts)
    client_cert, client_key = ca.issue("env_server client", client=True)
    tokens = {name: new_token() for name in clients}
    files = {
        "ca.pem": (ca.cert_pem, False),
        "ca.key": (ca.key_pem, True),
        "server.pem": (server_cert, False),
        "server.key": (server_key, True),
        "client.pem": (client_cert, False),
        "client.key": (client_key, True),
        "tokens": ("".join(f"{n}:{t}\n" for n, t in tokens.items()).encode(), True),
        **{f"{n}.token": (f"{n}:{t}\n".encode(), True) for n, t in tokens.items()},
    }
    paths = {}
    for name, (data, secret) in files.items():
        paths[name] = out / name
        _write(paths[name], data, secret)
    return paths


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m env_server.tools.devcerts", description=__doc__.splitlines()[0])
    p.add_argument("--out", required=True, help="directory to write into (created if missing)")
    p.add_argument(
        "--host", action="append", help="name or IP address the server certificate is valid for (repeatable)"
    )
    p.add_argument("--client", action="append", help="client name to make a token for (repeatable; default learner)")
    args = p.parse_args(argv)
    hosts = args.host or ["127.0.0.1", "localhost"]
    paths = write_all(pathlib.Path(args.out), hosts, args.client or ["learner"])
    print(f"wrote {', '.join(sorted(paths))} into {args.out} (server certificate for {', '.join(hosts)})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
