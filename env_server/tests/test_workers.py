"""Sessions whose instances run in worker processes (MakeRequest.num_workers).

The contract: a session with workers is indistinguishable from one without, except
in speed; errors name the same instance; a dead worker fails its session, not the server.
"""

from __future__ import annotations

import grpc
import numpy as np
import pytest
from conftest import make, rpc_error, running_server, step

from env_server._proto.mo_env.v1 import env_pb2 as pb
from env_server._proto.mo_env.v1 import env_pb2_grpc
from env_server.construction import make_session
from env_server.errors import InvalidArgument, SimulatorError
from env_server.registry import Registry
from env_server.session import Autoreset


def _trajectory(num_workers: int, autoreset: Autoreset, steps: int = 40) -> list[object]:
    """Everything a client sees from `steps` random Steps of 5 dst instances."""
    session = make_session(Registry().resolve("dst"), 5, {}, seed=3, autoreset=autoreset, num_workers=num_workers)
    rng = np.random.default_rng(0)
    seen: list[object] = []
    try:
        seen.append(session.reset().observation[0][1].copy())
        for _ in range(steps):
            r = session.step_actions(rng.integers(0, 4, size=5))
            seen += [r.observation[0][1].copy(), r.reward.copy(), r.terminated.copy(), r.truncated.copy()]
            seen += [(e.env_index, e.episode_return.tolist(), e.length) for e in r.episodes]
            seen += [arr.copy() for _, arr in r.final_observation]
            if autoreset is Autoreset.DISABLED and (r.terminated | r.truncated).any():
                ended = np.flatnonzero(r.terminated | r.truncated).tolist()
                seen.append(session.reset(ended).observation[0][1].copy())
    finally:
        session.close()
    return seen


@pytest.mark.parametrize("autoreset", list(Autoreset))
def test_workers_give_the_same_results(autoreset: Autoreset) -> None:
    # 5 instances in 3 shares (2 here, 2 and 1 in workers): uneven, and episodes end
    # and reset inside every share.
    inline, pooled = _trajectory(0, autoreset), _trajectory(2, autoreset)
    assert len(inline) == len(pooled)
    for a, b in zip(inline, pooled):
        if isinstance(a, np.ndarray):
            np.testing.assert_array_equal(a, b)
        else:
            assert a == b


def test_num_workers_out_of_range() -> None:
    with pytest.raises(InvalidArgument, match=r"num_workers: expected 0 .* to num_envs - 1 = 2 .*, got 3"):
        make_session(Registry().resolve("dst"), 3, {}, num_workers=3)


def test_dead_worker_fails_its_session_with_a_clear_error() -> None:
    session = make_session(Registry().resolve("dst"), 2, {}, num_workers=1)
    try:
        session.reset()
        worker = session._instances._workers[0]
        worker.process.kill()
        worker.process.join()
        with pytest.raises(SimulatorError, match=r"instance 1: WorkerDied: the worker process for instances 1\.\.1"):
            session.step_actions(np.array([1, 1]))
    finally:
        session.close()
    assert not worker.process.is_alive()


def test_close_stops_the_workers() -> None:
    session = make_session(Registry().resolve("dst"), 3, {}, num_workers=2)
    processes = [w.process for w in session._instances._workers]
    assert all(p.is_alive() for p in processes)
    session.close()
    assert [p.exitcode for p in processes] == [0, 0]


def test_simulator_exception_in_a_worker_over_the_wire() -> None:
    with running_server("--max-workers", "2") as addr, grpc.insecure_channel(addr) as channel:
        stub = env_pb2_grpc.EnvServiceStub(channel)
        err = rpc_error(make, stub, "faulty", 4, num_workers=3)
        assert err.code() == grpc.StatusCode.INVALID_ARGUMENT
        assert err.details() == "num_workers: expected at most 2 (this server's --max-workers), got 3"
        other = make(stub, "dst", 2).session_id
        stub.Reset(pb.ResetRequest(session_id=other))
        faulty = make(stub, "faulty", 3, num_workers=2).session_id
        stub.Reset(pb.ResetRequest(session_id=faulty))
        # Instance 1 is the first worker's whole share.
        err = rpc_error(step, stub, faulty, np.array([1, 3, 1]))
        assert err.code() == grpc.StatusCode.INTERNAL
        assert err.details() == f"env faulty session {faulty} instance 1: RuntimeError: the simulator exploded"
        err = rpc_error(step, stub, faulty, np.array([1, 1, 1]))
        assert err.code() == grpc.StatusCode.FAILED_PRECONDITION and "call Reset before Step" in err.details()
        assert list(step(stub, other, np.array([1, 1])).terminated) == [False, False]
        stub.Reset(pb.ResetRequest(session_id=faulty))
        assert list(step(stub, faulty, np.array([2, 0, 2])).terminated) == [False, False, False]
        stub.Close(pb.CloseRequest(session_id=faulty))


def test_workers_exit_when_the_server_goes_away() -> None:
    session = make_session(Registry().resolve("dst"), 2, {}, num_workers=1)
    process = session._instances._workers[0].process
    # What a killed server leaves behind: the worker's pipe closes without a goodbye.
    session._instances._workers[0].conn.close()
    process.join(timeout=10)
    assert process.exitcode == 0
    session.close()  # and closing what is left does not fail
