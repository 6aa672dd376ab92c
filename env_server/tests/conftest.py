"""Fixtures: real `python -m env_server` subprocesses on 127.0.0.1 with OS-chosen ports,
through each front (native tonic and grpc.aio).

Every server gets tests/plugins on its PYTHONPATH, so the test-only Tasks there are
registered through a real `env_server.envs` entry point.
"""

from __future__ import annotations

import contextlib
import os
import pathlib
import subprocess
import sys
import threading
from collections.abc import Iterator

import grpc
import numpy as np
import pytest

from env_server._proto.mo_env.v1 import env_pb2 as pb
from env_server._proto.mo_env.v1 import env_pb2_grpc
from env_server.client import to_tensor

PLUGINS = pathlib.Path(__file__).parent / "plugins"


def server_env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(PLUGINS), env.get("PYTHONPATH", "")]))
    return env


@contextlib.contextmanager
def running_server(
    *args: str, timeout: float = 30.0, extra_env: dict[str, str] | None = None, cwd: str | None = None
) -> Iterator[str]:
    """Start a server (in `cwd`, default this process's), yield its address from the LISTENING
    line, stop it at the end."""
    with server_process(*args, timeout=timeout, extra_env=extra_env, cwd=cwd) as (_, address):
        yield address


@contextlib.contextmanager
def server_process(
    *args: str, timeout: float = 30.0, extra_env: dict[str, str] | None = None, cwd: str | None = None
) -> Iterator[tuple[subprocess.Popen, str]]:
    """running_server, yielding the server's process too."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "env_server", "--port", "0", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        env={**server_env(), **(extra_env or {})},
        cwd=cwd,
    )
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.append(proc.stdout.readline()), daemon=True)
    reader.start()
    reader.join(timeout)
    try:
        assert lines and lines[0].startswith("LISTENING "), f"server did not report LISTENING: {lines}"
        yield proc, lines[0].split()[1]
    finally:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


# Both transports serve the same EnvService; every test on the shared server runs on each.
FRONTS = ("native", "grpcio")


@pytest.fixture(scope="session", params=FRONTS)
def address(request: pytest.FixtureRequest) -> Iterator[str]:
    with running_server("--front", request.param) as addr:
        yield addr


@pytest.fixture(scope="session")
def stub(address: str) -> Iterator[env_pb2_grpc.EnvServiceStub]:
    channel = grpc.insecure_channel(address)
    yield env_pb2_grpc.EnvServiceStub(channel)
    channel.close()


def make(stub: env_pb2_grpc.EnvServiceStub, env_id: str, num_envs: int = 1, **fields) -> pb.MakeResponse:
    return stub.Make(pb.MakeRequest(env_id=env_id, num_envs=num_envs, **fields))


def step(stub: env_pb2_grpc.EnvServiceStub, session_id: str, arr: np.ndarray) -> pb.StepResponse:
    return stub.Step(pb.StepRequest(session_id=session_id, action=to_tensor(arr)))


def rpc_error(call, *args, **kwargs) -> grpc.RpcError:
    """The RpcError a call raises (fails the test if it succeeds)."""
    with pytest.raises(grpc.RpcError) as info:
        call(*args, **kwargs)
    return info.value


def read_addresses(path: str) -> list[str]:
    """The addresses in an address file, as the agent reads it (comments and blank lines skipped)."""
    try:
        with open(path) as f:
            lines = [line.strip() for line in f]
    except FileNotFoundError:
        return []
    return [line for line in lines if line and not line.startswith("#")]


def proc_stat(pid: int | str) -> list[str]:
    """The fields of /proc/PID/stat after the command name: state, ppid, ..."""
    with open(f"/proc/{pid}/stat") as f:
        return f.read().rsplit(")", 1)[1].split()
