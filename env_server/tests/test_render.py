"""Render over both fronts: frames, sizes, cameras, instances, limits and every error code."""

from __future__ import annotations

import grpc
import numpy as np
import pytest
from conftest import make, rpc_error, running_server

from env_server import render
from env_server._proto.mo_env.v1 import env_pb2 as pb
from env_server._proto.mo_env.v1 import env_pb2_grpc
from env_server.client import RemoteVectorEnv, from_tensor


@pytest.fixture(scope="module")
def dst(stub) -> str:
    """A reset dst session of 3 instances; instance 1 has moved right once."""
    session_id = make(stub, "dst", 3).session_id
    stub.Reset(pb.ResetRequest(session_id=session_id))
    stub.Step(
        pb.StepRequest(
            session_id=session_id,
            action=pb.Tensor(dtype=pb.DTYPE_INT64, shape=[3], data=np.array([0, 1, 0], np.int64).tobytes()),
        )
    )
    return session_id


def _render(stub, session_id: str, **fields) -> np.ndarray:
    return from_tensor(stub.Render(pb.RenderRequest(session_id=session_id, **fields)).frames)


def test_capability(stub) -> None:
    assert "render" in stub.GetVersion(pb.GetVersionRequest()).capabilities


def test_default_size_every_instance(stub, dst) -> None:
    frames = _render(stub, dst)
    assert frames.shape == (3, render.DEFAULT_HEIGHT, render.DEFAULT_WIDTH, 3) and frames.dtype == np.uint8
    np.testing.assert_array_equal(frames[0], frames[2])  # same state, same picture
    assert not np.array_equal(frames[0], frames[1])  # the submarine moved


def test_size_and_chosen_instances(stub, dst) -> None:
    frames = _render(stub, dst, env_indices=[1, 0], width=64, height=48)
    assert frames.shape == (2, 48, 64, 3)
    np.testing.assert_array_equal(frames, _render(stub, dst, width=64, height=48)[[1, 0]])


@pytest.mark.parametrize(
    ("fields", "code", "names"),
    [
        ({"width": -1}, "INVALID_ARGUMENT", ["width", "-1"]),
        ({"height": -5}, "INVALID_ARGUMENT", ["height", "-5"]),
        ({"env_indices": [3]}, "INVALID_ARGUMENT", ["env_indices", "got 3"]),
        ({"camera": "nope"}, "INVALID_ARGUMENT", ["camera", "'nope'"]),
        ({"width": 5000, "height": 10}, "RESOURCE_EXHAUSTED", ["width", "4096", "5000"]),
        ({"width": 2000, "height": 2000}, "RESOURCE_EXHAUSTED", ["2073600", "2000 x 2000"]),
    ],
)
def test_bad_request(stub, dst, fields, code, names) -> None:
    err = rpc_error(stub.Render, pb.RenderRequest(session_id=dst, **fields))
    assert err.code() == grpc.StatusCode[code], err.details()
    for name in names:
        assert name in err.details()


def test_frames_per_call_limit(stub) -> None:
    session_id = make(stub, "dst", render.MAX_FRAMES + 1).session_id
    stub.Reset(pb.ResetRequest(session_id=session_id))
    err = rpc_error(stub.Render, pb.RenderRequest(session_id=session_id, width=8, height=8))
    assert err.code() == grpc.StatusCode.RESOURCE_EXHAUSTED
    assert (
        f"at most {render.MAX_FRAMES} frames" in err.details() and f"asked for {render.MAX_FRAMES + 1}" in err.details()
    )
    assert _render(stub, session_id, env_indices=list(range(render.MAX_FRAMES)), width=8, height=8).shape[0] == 64
    stub.Close(pb.CloseRequest(session_id=session_id))


def test_unknown_session(stub) -> None:
    err = rpc_error(stub.Render, pb.RenderRequest(session_id="nope"))
    assert err.code() == grpc.StatusCode.NOT_FOUND


def test_before_reset(stub) -> None:
    session_id = make(stub, "dst", 2).session_id
    err = rpc_error(stub.Render, pb.RenderRequest(session_id=session_id))
    assert err.code() == grpc.StatusCode.FAILED_PRECONDITION
    assert "call Reset before Render" in err.details()
    stub.Close(pb.CloseRequest(session_id=session_id))


def test_task_without_renderer(stub) -> None:
    session_id = make(stub, "faulty").session_id
    stub.Reset(pb.ResetRequest(session_id=session_id))
    err = rpc_error(stub.Render, pb.RenderRequest(session_id=session_id))
    assert err.code() == grpc.StatusCode.FAILED_PRECONDITION
    assert "FaultyTask has no renderer" in err.details()
    stub.Close(pb.CloseRequest(session_id=session_id))


def test_named_cameras(address) -> None:
    with RemoteVectorEnv(address, "humanoid-run", 1, seed=0) as env:
        env.reset()
        default = env.render(width=48, height=32)
        assert env.cameras == ("back", "side", "egocentric")
        assert env.render_fps == pytest.approx(40.0)  # 0.025 s per control step
        side = env.render(width=48, height=32, camera="side")
        back = env.render(width=48, height=32, camera="back")
    np.testing.assert_array_equal(default, side)  # humanoid-run's default view
    assert not np.array_equal(side, back)


def test_workers_render_the_same_frames(address) -> None:
    frames = []
    for workers in (0, 2):
        with RemoteVectorEnv(address, "shadow-turn", 3, seed=4, num_workers=workers) as env:
            env.reset()
            env.step(np.full((3, 20), 0.3, np.float32))
            frames.append(env.render(width=40, height=30))
    np.testing.assert_array_equal(frames[0], frames[1])


def test_response_over_the_message_limit() -> None:
    with running_server("--max-message-mb", "1") as addr, grpc.insecure_channel(addr) as channel:
        stub = env_pb2_grpc.EnvServiceStub(channel)
        session_id = make(stub, "dst", 4).session_id
        stub.Reset(pb.ResetRequest(session_id=session_id))
        err = rpc_error(stub.Render, pb.RenderRequest(session_id=session_id, width=640, height=480))
        assert err.code() == grpc.StatusCode.RESOURCE_EXHAUSTED
        assert "--max-message-mb" in err.details() and "4 frames of 640 x 480" in err.details()


def test_without_opengl() -> None:
    """MUJOCO_GL=disable: MuJoCo frames are FAILED_PRECONDITION naming the fix; DST still draws."""
    with running_server(extra_env={"MUJOCO_GL": "disable"}) as addr:
        with RemoteVectorEnv(addr, "humanoid-run", 1, seed=0) as env:
            env.reset()
            with pytest.raises(Exception) as info:
                env.render()
            assert info.value.code == grpc.StatusCode.FAILED_PRECONDITION
            assert "MUJOCO_GL=disable" in info.value.message and "apt-get install" in info.value.message
        with RemoteVectorEnv(addr, "dst", 1) as env:
            env.reset()
            assert env.render(width=20, height=22).shape == (1, 22, 20, 3)


@pytest.mark.parametrize(("env_id", "action"), [("shadow-turn", 0.5), ("humanoid-mocap", 0.0)])
def test_frames_follow_the_simulation(address, env_id, action) -> None:
    """Frames change as the task moves and repeat while it stands still, also after a
    dm_control task rendered in the same server, and across composer's per-episode
    recompiles (humanoid-mocap)."""
    with RemoteVectorEnv(address, "humanoid-run", 1, seed=0) as env:
        env.reset()
        env.render(width=32, height=24)
    with RemoteVectorEnv(address, env_id, 1, seed=0, autoreset="disabled") as env:
        env.reset()
        first = env.render(width=64, height=48)
        np.testing.assert_array_equal(first, env.render(width=64, height=48))
        for _ in range(5):
            env.step(np.full((1, *env.session_spec.action_space.shape), action, np.float32))
        moved = env.render(width=64, height=48)
        np.testing.assert_array_equal(moved, env.render(width=64, height=48))
    assert np.abs(moved.astype(int) - first.astype(int)).mean() > 1.0
