"""Session lifetime: leases after a client dies, StepStream breaks, health, version, shutdown."""

from __future__ import annotations

import pathlib
import queue
import subprocess
import sys
import textwrap
import time

import grpc
import numpy as np
from conftest import make, rpc_error, running_server, server_env
from grpc_health.v1 import health_pb2, health_pb2_grpc

import env_server
from env_server._proto.mo_env.v1 import env_pb2 as pb
from env_server._proto.mo_env.v1 import env_pb2_grpc
from env_server.client import to_tensor

CLIENT = textwrap.dedent(
    """
    import sys, grpc
    from env_server._proto.mo_env.v1 import env_pb2 as pb, env_pb2_grpc
    stub = env_pb2_grpc.EnvServiceStub(grpc.insecure_channel(sys.argv[1]))
    sid = stub.Make(pb.MakeRequest(env_id="dst", num_envs=1)).session_id
    print("MADE", sid, flush=True)
    sys.stdin.read()
    """
)


def _poll(predicate, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.2)
    return False


def test_killed_client_session_expires_with_lease() -> None:
    with running_server("--max-sessions", "1", "--session-lease", "2") as addr, grpc.insecure_channel(addr) as ch:
        stub = env_pb2_grpc.EnvServiceStub(ch)
        client = subprocess.Popen(
            [sys.executable, "-c", CLIENT, addr],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            env=server_env(),
        )
        assert client.stdout.readline().startswith("MADE")
        client.kill()
        client.wait()
        assert rpc_error(make, stub, "dst").code() == grpc.StatusCode.RESOURCE_EXHAUSTED

        def slot_free() -> bool:
            try:
                make(stub, "dst")
                return True
            except grpc.RpcError as err:
                assert err.code() == grpc.StatusCode.RESOURCE_EXHAUSTED
                return False

        assert _poll(slot_free, 8.0), "the dead client's session was not reaped after its 2 s lease"


def _stream(stub, session_id: str, steps: int):
    """A StepStream that sends `steps` requests, then keeps the stream open until told to stop."""
    requests: queue.Queue = queue.Queue()
    action = to_tensor(np.array([1], np.int64))
    for _ in range(steps):
        requests.put(pb.StepRequest(session_id=session_id, action=action))

    def gen():
        while (item := requests.get()) is not None:
            yield item

    return stub.StepStream(gen()), requests


def test_step_stream_break_closes_sessions(stub) -> None:
    session_id = make(stub, "dst").session_id
    stub.Reset(pb.ResetRequest(session_id=session_id))
    call, requests = _stream(stub, session_id, 3)
    observations = [list(np.frombuffer(next(call).observation[0].tensor.data, np.float32)) for _ in range(3)]
    assert observations == [[0, 1], [0, 2], [0, 3]]  # in order, one response per request
    call.cancel()
    requests.put(None)

    def closed() -> bool:
        try:
            stub.Reset(pb.ResetRequest(session_id=session_id))
            return False
        except grpc.RpcError as err:
            return err.code() == grpc.StatusCode.NOT_FOUND

    assert _poll(closed, 5.0)


def test_step_stream_end_closes_sessions_but_errors_do_not(stub) -> None:
    session_id = make(stub, "dst").session_id
    stub.Reset(pb.ResetRequest(session_id=session_id))
    bad = pb.StepRequest(session_id=session_id, action=to_tensor(np.array([7], np.int64)))
    good = pb.StepRequest(session_id=session_id, action=to_tensor(np.array([1], np.int64)))
    responses = stub.StepStream(iter([good, bad, good]))
    assert next(responses).terminated == [False]
    err = rpc_error(next, responses)
    assert err.code() == grpc.StatusCode.INVALID_ARGUMENT and "env 0 = 7" in err.details()
    stub.Reset(pb.ResetRequest(session_id=session_id))  # an error status leaves the session open

    call, requests = _stream(stub, session_id, 2)
    requests.put(None)  # the client half-closes: the stream ends and takes its sessions along
    assert len(list(call)) == 2
    err = rpc_error(stub.Reset, pb.ResetRequest(session_id=session_id))
    assert err.code() == grpc.StatusCode.NOT_FOUND


def test_version_and_health(address: str, stub) -> None:
    version = stub.GetVersion(pb.GetVersionRequest())
    assert version.protocol_version == "1.0.0" and version.server_version == env_server.__version__
    for flag in (
        "step_stream",
        "autoreset.same_step",
        "autoreset.next_step",
        "autoreset.disabled",
        "dict_observations",
        "info_keys",
        "episode_returns",
        "close_session",
    ):
        assert flag in version.capabilities
    assert version.max_message_bytes == 64 * 1024 * 1024
    with grpc.insecure_channel(address) as ch:
        health = health_pb2_grpc.HealthStub(ch)
        for service in ("", "mo_env.v1.EnvService"):
            status = health.Check(health_pb2.HealthCheckRequest(service=service)).status
            assert status == health_pb2.HealthCheckResponse.SERVING


def test_server_started_from_the_repository_root_is_the_installed_package() -> None:
    # The docs and the agent start `python -m env_server` from the repository root, which
    # holds a folder named env_server/ (this package's project). If that folder were imported
    # as a namespace package, __init__ would not run (no __version__, no OpenGL backend
    # choice) and GetVersion would fail as an internal error.
    root = pathlib.Path(__file__).resolve().parents[2]
    assert (root / "env_server" / "env_server" / "__init__.py").is_file()
    with running_server(cwd=str(root)) as address, grpc.insecure_channel(address) as channel:
        version = env_pb2_grpc.EnvServiceStub(channel).GetVersion(pb.GetVersionRequest())
    assert version.server_version == env_server.__version__


def test_close_session_and_its_deprecated_alias_close(stub) -> None:
    """CloseSession is the name; Close (hidden by gRPC's JavaScript library) still works."""
    for close in (stub.CloseSession, stub.Close):
        session_id = make(stub, "dst").session_id
        assert close(pb.CloseRequest(session_id=session_id)) == pb.CloseResponse()
        for again in (stub.CloseSession, stub.Close):
            err = rpc_error(again, pb.CloseRequest(session_id=session_id))
            assert err.code() == grpc.StatusCode.NOT_FOUND and session_id in err.details()


def test_list_envs_rpc(stub) -> None:
    envs = {e.env_id: [o.name for o in e.objectives] for e in stub.ListEnvs(pb.ListEnvsRequest()).envs}
    assert envs["dst"] == ["time", "treasure"]
    assert envs["humanoid-run"] == ["task", "action_norm"]
    assert envs["faulty"] == ["steps"]  # the test plug-in, through its entry point
    assert not any(":" in env_id for env_id in envs)


def test_info_keys_reported(stub) -> None:
    session_id = make(stub, "faulty", 2, info_keys=["position"]).session_id
    reset = stub.Reset(pb.ResetRequest(session_id=session_id))
    assert reset.info[0].name == "position"
    response = stub.Step(pb.StepRequest(session_id=session_id, action=to_tensor(np.array([2, 0], np.int64))))
    info = {t.name: np.frombuffer(t.tensor.data, np.int64).tolist() for t in response.info}
    assert info == {"position": [1, -1]}
    stub.Close(pb.CloseRequest(session_id=session_id))


def test_sigterm_shuts_down_cleanly() -> None:
    proc = subprocess.Popen(
        [sys.executable, "-m", "env_server", "--port", "0"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=server_env(),
    )
    line = proc.stdout.readline()
    assert line.startswith("LISTENING 127.0.0.1:") and int(line.strip().rsplit(":", 1)[1]) > 0
    with grpc.insecure_channel(line.split()[1]) as ch:
        make(env_pb2_grpc.EnvServiceStub(ch), "dst")
    proc.terminate()
    _, err = proc.communicate(timeout=15)
    assert proc.returncode == 0
    assert "server shutdown" in err  # the open session was closed on the way out
