"""examples/plugin, as a user would install it: a real server loads it through the entry
point its pyproject.toml declares, and gymnasium's check_env passes on it over gRPC.

Installing the package into the shared venv would register it for every other test, so
the test builds what `pip install` would leave on sys.path instead: the package's
source directory, and a dist-info whose entry_points.txt is generated from the
pyproject's own `[project.entry-points."env_server.envs"]` table.
"""

from __future__ import annotations

import pathlib
import warnings

import numpy as np
import pytest
from conftest import running_server, server_env
from gymnasium.utils.env_checker import check_env

from env_server.client import InvalidArgumentError, RemoteEnv

tomllib = pytest.importorskip("tomllib")  # Python 3.11+ (the venv's); env_server also supports 3.10

EXAMPLE = pathlib.Path(__file__).resolve().parents[2] / "examples" / "plugin"
PYPROJECT = tomllib.loads((EXAMPLE / "pyproject.toml").read_text())
ENV_ID = "reach-energy"


def installed(root: pathlib.Path) -> str:
    """A PYTHONPATH on which the example is installed as pip would (metadata + source)."""
    project = PYPROJECT["project"]
    info = root / f"{project['name'].replace('-', '_')}-{project['version']}.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {project['name']}\nVersion: {project['version']}\n")
    points = project["entry-points"]["env_server.envs"]
    (info / "entry_points.txt").write_text(
        "[env_server.envs]\n" + "".join(f"{name} = {value}\n" for name, value in points.items())
    )
    return ":".join([str(root), str(EXAMPLE / "src"), server_env()["PYTHONPATH"]])


@pytest.fixture(scope="module")
def address(tmp_path_factory: pytest.TempPathFactory):
    pythonpath = installed(tmp_path_factory.mktemp("site"))
    with running_server(extra_env={"PYTHONPATH": pythonpath}) as addr:
        yield addr


def test_check_env_passes_over_grpc(address: str) -> None:
    env = RemoteEnv(address, ENV_ID, render_mode="rgb_array", render_width=64, render_height=8)
    try:
        with warnings.catch_warnings():
            # The only warnings are gymnasium's about the reward not being a scalar.
            warnings.simplefilter("ignore")
            check_env(env)
    finally:
        env.close()


def test_objectives_dynamics_and_seeding(address: str) -> None:
    env = RemoteEnv(address, ENV_ID, step_size=0.5)
    try:
        assert env.objective_names == ("reach", "energy")
        np.testing.assert_allclose(env.reward_space.low, [-1.8, -1.0], rtol=1e-6)
        np.testing.assert_allclose(env.reward_space.high, [0.0, 0.0])
        obs, _ = env.reset(seed=7)
        assert env.reset(seed=7)[0] == obs  # a seed fixes the start
        x = float(obs[0])
        # x <- clip(x + 0.5 a, -1, 1); reach = -|x - 0.8| after the move, energy = -a^2.
        for a in (0.6, -1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0):
            obs, reward, terminated, truncated, _ = env.step(np.array([a], np.float32))
            x = min(1.0, max(-1.0, x + 0.5 * np.float32(a)))
            np.testing.assert_allclose(obs, [x], rtol=1e-6)
            np.testing.assert_allclose(reward, [-abs(x - 0.8), -(np.float32(a) ** 2)], rtol=1e-5)
            assert not terminated and not truncated
        assert x == 1.0  # +2.8 in all from x >= -1: the clip was reached
        for t in range(42):  # 50 steps, then the server truncates
            *_, truncated, info = env.step(np.zeros(1, np.float32))
            assert truncated == (t == 41)
        assert info["server_episode"]["length"] == 50
    finally:
        env.close()


def test_bad_step_size_is_the_callers_error(address: str) -> None:
    with pytest.raises(InvalidArgumentError, match=r"keyword 'step_size' expects a float .* got 'big'"):
        RemoteEnv(address, ENV_ID, step_size="big")
    with pytest.raises(InvalidArgumentError, match=r"ValueError: 'step_size: expected a number in \(0, 1\], got 2.0'"):
        RemoteEnv(address, ENV_ID, step_size=2.0)


def test_run_configs_bind_to_the_task(monkeypatch: pytest.MonkeyPatch) -> None:
    """The agent binds a config to the env by id and to its objectives by name, at run
    time; this checks that the example's configs agree with its Task."""
    monkeypatch.syspath_prepend(str(EXAMPLE / "src"))
    from reach_energy.task import ReachEnergy

    names = [o.name for o in ReachEnergy.objectives]
    run = tomllib.loads((EXAMPLE / "mompo.toml").read_text())
    assert run["env"]["id"] == ENV_ID and ENV_ID in PYPROJECT["project"]["entry-points"]["env_server.envs"]
    assert [o["name"] for o in run["learner"]["objectives"]] == names
    # energy is -a^2, not -||a||_2: it must be learned, never the closed form.
    assert all(o.get("source", "learned") == "learned" for o in run["learner"]["objectives"])
    sweep = tomllib.loads((EXAMPLE / "sweep.toml").read_text())
    assert sweep["base"] == "mompo.toml"
    assert sorted(sweep["grid"]["product"]) == sorted(names)
    # The reference point: every objective at its worst for all 50 steps.
    worst = {o.name: o.min * ReachEnergy.max_episode_steps for o in ReachEnergy.objectives}
    assert sweep["reference_point"] == pytest.approx(worst)
