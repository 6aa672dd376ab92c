"""Registry: shipped ids, prefix adapters, and real entry points from a dist-info on sys.path."""

from __future__ import annotations

import pathlib
import re
import subprocess
import sys
import textwrap

import pytest
from conftest import server_env

from env_server.envs import REGISTRY
from env_server.errors import InvalidArgument, NotFound
from env_server.registry import Registry, RegistryError, construct

PLUGIN = textwrap.dedent(
    """
    import gymnasium, numpy as np
    from env_server.task import Objective, StepOutcome, Task

    class Coin(Task):
        description = "flip a biased coin"
        objectives = (Objective("heads", "1 on heads", 0.0, 1.0), Objective("tails", "1 on tails", 0.0, 1.0))

        def __init__(self, bias: float = 0.5):
            self.bias = bias
            self.observation_space = gymnasium.spaces.Box(0.0, 1.0, (1,), np.float32)
            self.action_space = gymnasium.spaces.Discrete(1)
            self.rng = np.random.default_rng()

        def reset(self, seed=None):
            self.rng = np.random.default_rng(seed)
            return np.zeros(1, np.float32), {}

        def step(self, action):
            heads = float(self.rng.random() < self.bias)
            return StepOutcome(np.array([heads], np.float32), np.array([heads, 1 - heads], np.float32), True, False)
    """
)


def write_plugin(root: pathlib.Path, entry_name: str) -> pathlib.Path:
    (root / "coin_pkg").mkdir(parents=True)
    (root / "coin_pkg" / "__init__.py").write_text(PLUGIN)
    info = root / "coin_pkg-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: coin_pkg\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text(f"[env_server.envs]\n{entry_name} = coin_pkg:Coin\n")
    return root


def test_entry_point_env_is_registered(tmp_path, monkeypatch) -> None:
    monkeypatch.syspath_prepend(str(write_plugin(tmp_path, "coin")))
    registry = Registry()
    entry = registry.resolve("coin")
    assert entry.origin == "entry point coin = coin_pkg:Coin"
    assert [o.name for o in entry.objectives] == ["heads", "tails"]
    assert "coin" in [e.env_id for e in registry.entries()]
    task = construct(entry, {"bias": 1.0})
    task.reset(seed=0)
    assert task.step(0).reward.tolist() == [1.0, 0.0]
    with pytest.raises(InvalidArgument, match="'weight'"):
        construct(entry, {"weight": 2})


def test_entry_point_clash_with_shipped_id(tmp_path, monkeypatch) -> None:
    monkeypatch.syspath_prepend(str(write_plugin(tmp_path, "dst")))
    with pytest.raises(RegistryError) as info:
        Registry()
    assert "'dst'" in str(info.value) and "shipped" in str(info.value) and "coin_pkg:Coin" in str(info.value)


def test_server_refuses_to_start_on_clash(tmp_path) -> None:
    env = server_env()
    env["PYTHONPATH"] = f"{write_plugin(tmp_path, 'humanoid-run')}:{env['PYTHONPATH']}"
    proc = subprocess.run([sys.executable, "-m", "env_server", "--list"], capture_output=True, text=True, env=env)
    assert proc.returncode == 2
    assert "'humanoid-run' is registered twice" in proc.stderr and "coin_pkg:Coin" in proc.stderr


def test_prefix_resolution() -> None:
    registry = Registry(load_entry_points=False)
    assert registry.resolve("dmc:ball_in_cup-catch").factory.args == ("ball_in_cup", "catch")
    assert registry.resolve("gym:CartPole-v1").factory.args == ("CartPole-v1",)
    with pytest.raises(NotFound, match="dmc:<domain>-<task>"):
        registry.resolve("dmc:humanoid-fly")
    # The message lists every shipped id (sorted), so a user sees what exists.
    known = ", ".join(sorted(REGISTRY))
    with pytest.raises(NotFound, match=f"known: {re.escape(known)};"):
        registry.resolve("nope")
