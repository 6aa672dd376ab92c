"""File kwargs (clip_path, xml_file, ...) reach only the shipped assets and --data-dir:
anything else is PERMISSION_DENIED without saying whether it exists, and a file that
does not load is INVALID_ARGUMENT without quoting it."""

from __future__ import annotations

import json
import os
import pathlib

import grpc
import numpy as np
import pytest
from conftest import FRONTS, make, rpc_error, running_server, step

from env_server._proto.mo_env.v1 import env_pb2 as pb
from env_server._proto.mo_env.v1 import env_pb2_grpc

SECRET = "secret_element_name_7f3a"


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory) -> pathlib.Path:
    d = tmp_path_factory.mktemp("data")
    (d / "broken.xml").write_text(f"<mujoco><{SECRET} attr='{SECRET}'/><worldbody><oops></mujoco>")
    (d / "broken.h5").write_text(f"not hdf5 {SECRET}")
    (d / "passwd-link.xml").symlink_to("/etc/passwd")
    return d


@pytest.fixture(scope="module", params=FRONTS)
def server(request, data_dir) -> env_pb2_grpc.EnvServiceStub:
    with running_server("--front", request.param, "--data-dir", str(data_dir)) as addr:
        with grpc.insecure_channel(addr) as channel:
            yield env_pb2_grpc.EnvServiceStub(channel)


def _denied(stub, env_id: str, name: str, value: str) -> str:
    err = rpc_error(make, stub, env_id, 1, kwargs_json=json.dumps({name: value}))
    assert err.code() == grpc.StatusCode.PERMISSION_DENIED, (value, err.code(), err.details())
    return err.details()


@pytest.mark.parametrize(
    "env_id, name",
    [("humanoid-mocap", "clip_path"), ("gym:Hopper-v5", "xml_file"), ("mo:mo-hopper-v5", "xml_file")],
)
def test_a_file_outside_the_data_dirs_is_denied_without_saying_whether_it_exists(server, data_dir, env_id, name):
    paths = {
        "existing": "/etc/passwd",
        "missing": "/nonexistent/clips.h5",
        "dotdot": f"{data_dir}/../../../../etc/passwd",
        "relative dotdot": "../../../../../../../../etc/passwd",
        "symlink out": str(data_dir / "passwd-link.xml"),
        "a directory": str(data_dir),
        "nul byte": "/etc/passwd\0.xml",
    }
    messages = {kind: _denied(server, env_id, name, value) for kind, value in paths.items()}
    for kind, message in messages.items():
        # Identical but for the quoted value: nothing tells missing from existing.
        assert message.replace(repr(paths[kind]), "<path>") == (
            f"kwargs_json: {name}: expected a file inside this server's data directories (the shipped "
            "assets and each --data-dir), got <path>, which is not one"
        ), (kind, message)


def test_a_file_that_does_not_load_is_invalid_argument_without_its_content(server, data_dir) -> None:
    for env_id, name, value in [
        ("gym:Hopper-v5", "xml_file", str(data_dir / "broken.xml")),
        ("gym:Hopper-v5", "xml_file", "broken.xml"),  # relative: looked up in the data dirs
        ("humanoid-mocap", "clip_path", str(data_dir / "broken.h5")),
    ]:
        err = rpc_error(make, server, env_id, 1, kwargs_json=json.dumps({name: value}))
        assert err.code() == grpc.StatusCode.INVALID_ARGUMENT, (value, err.details())
        assert err.details().startswith(
            f"kwargs_json: env '{env_id}' could not be built from the file named by {name} ("
        ), err.details()
        assert SECRET not in err.details() and str(data_dir) not in err.details(), err.details()


def test_shipped_assets_and_data_dir_files_still_load(server) -> None:
    # gymnasium's own relative xml_file names keep meaning its assets.
    session_id = make(server, "gym:Hopper-v5", 1, kwargs_json=json.dumps({"xml_file": "hopper.xml"})).session_id
    server.Reset(pb.ResetRequest(session_id=session_id))
    assert list(step(server, session_id, np.zeros((1, 3), np.float32)).reward.shape) == [1, 1]
    server.Close(pb.CloseRequest(session_id=session_id))
    hopper = os.path.join(os.path.dirname(__import__("gymnasium").__file__), "envs/mujoco/assets/hopper.xml")
    session_id = make(server, "gym:Hopper-v5", 1, kwargs_json=json.dumps({"xml_file": hopper})).session_id
    server.Close(pb.CloseRequest(session_id=session_id))


def test_a_file_kwarg_of_the_wrong_type(server) -> None:
    err = rpc_error(make, server, "humanoid-mocap", 1, kwargs_json=json.dumps({"clip_path": 3}))
    assert err.code() == grpc.StatusCode.INVALID_ARGUMENT
    assert err.details() == "kwargs_json: clip_path: expected a file name (a string), got 3"
