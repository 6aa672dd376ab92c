"""TLS, bearer tokens and session owners, through both fronts.

The CA, certificates and tokens are made at run time by env_server.tools.devcerts into a
temporary directory; no key is committed.
"""

from __future__ import annotations

import pathlib
import subprocess
import sys
from collections.abc import Iterator

import grpc
import numpy as np
import pytest
from conftest import FRONTS, running_server, server_env
from grpc_health.v1 import health_pb2, health_pb2_grpc

from env_server import security
from env_server._proto.mo_env.v1 import env_pb2 as pb
from env_server._proto.mo_env.v1 import env_pb2_grpc
from env_server.client import (
    RemoteError,
    RemoteVectorEnv,
    UnauthenticatedError,
    list_envs,
    read_token_file,
    to_tensor,
)
from env_server.tools import devcerts


@pytest.fixture(scope="module")
def certs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, pathlib.Path]:
    out = tmp_path_factory.mktemp("certs")
    paths = devcerts.write_all(out, ["127.0.0.1", "localhost"], ["alice", "bob"])
    paths["other-ca.pem"] = out / "other-ca.pem"
    paths["other-ca.pem"].write_bytes(devcerts.Authority("another CA").cert_pem)
    return paths


def _tls_args(certs: dict[str, pathlib.Path], *, mutual: bool = False) -> list[str]:
    args = ["--tls-cert", str(certs["server.pem"]), "--tls-key", str(certs["server.key"])]
    args += ["--auth-token-file", str(certs["tokens"])]
    return args + (["--tls-client-ca", str(certs["ca.pem"])] if mutual else [])


@pytest.fixture(scope="module", params=FRONTS)
def tls_address(request: pytest.FixtureRequest, certs: dict[str, pathlib.Path]) -> Iterator[str]:
    with running_server("--front", request.param, *_tls_args(certs)) as addr:
        yield addr


@pytest.fixture(scope="module", params=FRONTS)
def mtls_address(request: pytest.FixtureRequest, certs: dict[str, pathlib.Path]) -> Iterator[str]:
    with running_server("--front", request.param, *_tls_args(certs, mutual=True)) as addr:
        yield addr


def _ids(envs: list) -> set[str]:
    return {env_id for env_id, _, _ in envs}


# ---------------------------------------------------------------------- tokens over TLS
def test_good_token_over_tls_makes_steps_and_closes(tls_address: str, certs: dict[str, pathlib.Path]) -> None:
    connection = {"tls_ca": certs["ca.pem"], "token_file": certs["alice.token"]}
    assert "dst" in _ids(list_envs(f"https://{tls_address}", **connection))
    # A bare host:port with tls_ca= is TLS too.
    with RemoteVectorEnv(tls_address, "dst", 2, seed=0, **connection) as env:
        env.reset()
        _, reward, *_ = env.step(np.array([1, 2]))
        assert reward.shape == (2, 2)


def test_wrong_token_is_unauthenticated_without_echoing_it(tls_address: str, certs: dict[str, pathlib.Path]) -> None:
    wrong = "not-a-token-of-this-server-0123456789"
    with pytest.raises(UnauthenticatedError) as info:
        list_envs(f"https://{tls_address}", tls_ca=certs["ca.pem"], token=wrong)
    assert info.value.code == grpc.StatusCode.UNAUTHENTICATED
    assert info.value.message == security.UNKNOWN_TOKEN
    assert wrong not in str(info.value)


def test_no_token_is_unauthenticated(tls_address: str, certs: dict[str, pathlib.Path]) -> None:
    with pytest.raises(UnauthenticatedError) as info:
        RemoteVectorEnv(f"https://{tls_address}", "dst", 1, tls_ca=certs["ca.pem"])
    assert info.value.message == security.MISSING_TOKEN


def test_every_rpc_checks_the_token_and_health_needs_none(tls_address: str, certs: dict[str, pathlib.Path]) -> None:
    credentials = grpc.ssl_channel_credentials(certs["ca.pem"].read_bytes())
    with grpc.secure_channel(tls_address, credentials) as channel:
        stub = env_pb2_grpc.EnvServiceStub(channel)
        basic = (("authorization", "Basic YWxpY2U6cGFzc3dvcmQ="),)
        calls = {
            "GetVersion": lambda md: stub.GetVersion(pb.GetVersionRequest(), metadata=md),
            "Reset": lambda md: stub.Reset(pb.ResetRequest(session_id="x"), metadata=md),
            "Step": lambda md: stub.Step(pb.StepRequest(session_id="x"), metadata=md),
            "StepStream": lambda md: list(stub.StepStream(iter([pb.StepRequest(session_id="x")]), metadata=md)),
            "CloseSession": lambda md: stub.CloseSession(pb.CloseRequest(session_id="x"), metadata=md),
            "Close": lambda md: stub.Close(pb.CloseRequest(session_id="x"), metadata=md),
        }
        for name, call in calls.items():
            for metadata, message in (((), security.MISSING_TOKEN), (basic, security.MALFORMED_TOKEN)):
                with pytest.raises(grpc.RpcError) as info:
                    call(metadata)
                assert (info.value.code(), info.value.details()) == (grpc.StatusCode.UNAUTHENTICATED, message), name
        health = health_pb2_grpc.HealthStub(channel).Check(
            health_pb2.HealthCheckRequest(service="mo_env.v1.EnvService")
        )
        assert health.status == health_pb2.HealthCheckResponse.SERVING


def test_plain_client_to_tls_server_fails(tls_address: str, certs: dict[str, pathlib.Path]) -> None:
    with pytest.raises(RemoteError) as info:
        list_envs(tls_address, token_file=certs["alice.token"])
    assert info.value.code == grpc.StatusCode.UNAVAILABLE


def test_wrong_ca_fails(tls_address: str, certs: dict[str, pathlib.Path]) -> None:
    with pytest.raises(RemoteError) as info:
        list_envs(f"https://{tls_address}", tls_ca=certs["other-ca.pem"], token_file=certs["alice.token"])
    assert info.value.code == grpc.StatusCode.UNAVAILABLE


# ---------------------------------------------------------------------- mutual TLS
def test_mutual_tls_with_a_client_certificate_works(mtls_address: str, certs: dict[str, pathlib.Path]) -> None:
    envs = list_envs(
        f"https://{mtls_address}",
        tls_ca=certs["ca.pem"],
        tls_client_cert=certs["client.pem"],
        tls_client_key=certs["client.key"],
        token_file=certs["bob.token"],
    )
    assert "dst" in _ids(envs)


def test_mutual_tls_without_a_client_certificate_fails(mtls_address: str, certs: dict[str, pathlib.Path]) -> None:
    with pytest.raises(RemoteError) as info:
        list_envs(f"https://{mtls_address}", tls_ca=certs["ca.pem"], token_file=certs["bob.token"])
    assert info.value.code == grpc.StatusCode.UNAVAILABLE


# ---------------------------------------------------------------------- session owners
def test_a_session_answers_only_the_token_that_made_it(tls_address: str, certs: dict[str, pathlib.Path]) -> None:
    ca = certs["ca.pem"]
    alice = RemoteVectorEnv(tls_address, "dst", 1, seed=0, tls_ca=ca, token_file=certs["alice.token"])
    try:
        alice.reset()
        unknown = f"unknown session '{alice.session_id}' (closed, expired, or never made)"
        credentials = grpc.ssl_channel_credentials(ca.read_bytes())
        bob = (("authorization", f"Bearer {read_token_file(certs['bob.token'])}"),)
        with grpc.secure_channel(tls_address, credentials) as channel:
            stub = env_pb2_grpc.EnvServiceStub(channel)
            step = pb.StepRequest(session_id=alice.session_id, action=to_tensor(np.array([1])))
            calls = {
                "Reset": lambda: stub.Reset(pb.ResetRequest(session_id=alice.session_id), metadata=bob),
                "Step": lambda: stub.Step(step, metadata=bob),
                "StepStream": lambda: list(stub.StepStream(iter([step]), metadata=bob)),
                "CloseSession": lambda: stub.CloseSession(pb.CloseRequest(session_id=alice.session_id), metadata=bob),
                "Close": lambda: stub.Close(pb.CloseRequest(session_id=alice.session_id), metadata=bob),
            }
            for name, call in calls.items():
                with pytest.raises(grpc.RpcError) as info:
                    call()
                # The same answer as for an id that never existed: bob learns nothing.
                assert (info.value.code(), info.value.details()) == (grpc.StatusCode.NOT_FOUND, unknown), name
        # None of that touched alice's session.
        _, reward, *_ = alice.step(np.array([1]))
        assert reward.shape == (1, 2)
    finally:
        alice.close()


def test_a_token_without_tls_works_on_loopback(certs: dict[str, pathlib.Path]) -> None:
    for front in FRONTS:
        with running_server("--front", front, "--auth-token-file", str(certs["tokens"])) as addr:
            with pytest.raises(UnauthenticatedError):
                list_envs(addr)
            assert "dst" in _ids(list_envs(addr, token_file=certs["alice.token"]))


# ---------------------------------------------------------------------- startup rules
def _start(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "env_server", "--port", "0", *args],
        capture_output=True,
        text=True,
        env=server_env(),
        timeout=60,
    )


def test_a_non_loopback_bind_needs_tls_and_a_token_or_insecure(certs: dict[str, pathlib.Path]) -> None:
    plain = _start("--host", "0.0.0.0")
    assert plain.returncode == 2, plain.stderr
    assert "'0.0.0.0' is not a loopback address" in plain.stderr
    assert "has no TLS (--tls-cert, --tls-key) and no token (--auth-token-file)" in plain.stderr
    assert "--insecure" in plain.stderr
    tls_only = _start(
        "--host", "0.0.0.0", "--tls-cert", str(certs["server.pem"]), "--tls-key", str(certs["server.key"])
    )
    assert tls_only.returncode == 2 and "has no token (--auth-token-file)" in tls_only.stderr, tls_only.stderr
    with running_server("--host", "0.0.0.0", "--insecure") as addr:
        assert addr.startswith("0.0.0.0:")
    with running_server("--host", "0.0.0.0", *_tls_args(certs)) as addr:
        assert addr.startswith("0.0.0.0:")


@pytest.mark.parametrize(
    "content, expected",
    [
        ("short\n", "line 1: expected a token of at least 16 printable ASCII characters"),
        ("# only a comment\n", "expected at least one token line"),
        ("a:0123456789abcdef\na:fedcba9876543210\n", "expected unique names"),
        ("0123456789abcdef\n0123456789abcdef\n", "expected every token once"),
    ],
)
def test_bad_token_files_stop_the_server_without_quoting_tokens(
    tmp_path: pathlib.Path, content: str, expected: str
) -> None:
    path = tmp_path / "tokens"
    path.write_text(content)
    proc = _start("--auth-token-file", str(path))
    assert proc.returncode == 2 and expected in proc.stderr, proc.stderr
    assert "0123456789abcdef" not in proc.stderr and "short" not in proc.stderr.replace(str(path), "")


def test_tls_flags_must_come_together(certs: dict[str, pathlib.Path]) -> None:
    proc = _start("--tls-cert", str(certs["server.pem"]))
    assert proc.returncode == 2 and "--tls-cert and --tls-key: expected both or neither" in proc.stderr
    proc = _start("--tls-cert", str(certs["server.key"]), "--tls-key", str(certs["server.key"]))
    assert proc.returncode == 2 and "--tls-cert: expected a PEM file with a 'CERTIFICATE' block" in proc.stderr


def test_client_connection_arguments_are_checked(tmp_path: pathlib.Path, certs: dict[str, pathlib.Path]) -> None:
    with pytest.raises(ValueError, match="expected host:port or https://... with TLS files, got 'http://"):
        list_envs("http://127.0.0.1:1", tls_ca=certs["ca.pem"])
    with pytest.raises(ValueError, match="token, token_file: expected at most one"):
        list_envs("127.0.0.1:1", token="t" * 20, token_file=certs["alice.token"])
    with pytest.raises(ValueError, match="tls_client_cert, tls_client_key: expected both or neither"):
        list_envs("127.0.0.1:1", tls_client_cert=certs["client.pem"])
    assert read_token_file(certs["alice.token"]) == certs["tokens"].read_text().splitlines()[0].split(":")[1]
    both = tmp_path / "both"
    both.write_text(certs["tokens"].read_text())
    with pytest.raises(ValueError, match="expected exactly one token line in .*, got 2"):
        read_token_file(both)
