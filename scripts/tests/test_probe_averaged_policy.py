"""scripts/probe_averaged_policy.py: which checkpoints a window takes, what averaging
changes (the policy's tensors only), what `keep` copies, and its bad options."""

from __future__ import annotations

import argparse
import pathlib
import subprocess
import sys

import numpy as np
import probe_averaged_policy as probe
import pytest
from safetensors.numpy import save_file


def checkpoint(run: pathlib.Path, step: int, env: int, policy: list[float], critic: list[float]) -> pathlib.Path:
    d = run / "checkpoints" / f"step_{step:09d}_env_{env:012d}"
    d.mkdir(parents=True)
    tensors = {"policy/w": np.array(policy, dtype=np.float32), "critic/w": np.array(critic, dtype=np.float32)}
    save_file(tensors, str(d / "params.safetensors"))
    (d / "state.json").write_text("{}")
    return d


def test_the_policy_is_averaged_and_the_rest_is_the_last_checkpoints(tmp_path):
    folders = [
        checkpoint(tmp_path, 1000, 6000, [1, 2], [10, 20]),
        checkpoint(tmp_path, 2000, 7000, [3, 6], [30, 40]),
        checkpoint(tmp_path, 3000, 8000, [5, 1], [50, 60]),
    ]
    params = probe.averaged(folders)
    assert params["policy/w"].tolist() == [3.0, 3.0]
    assert params["policy/w"].dtype == np.float32
    assert params["critic/w"].tolist() == [50.0, 60.0]


def test_a_window_ends_at_the_latest_checkpoint_not_after_the_point(tmp_path):
    for i, env in enumerate(range(6000, 13000, 1000)):
        checkpoint(tmp_path, 1000 * (i + 1), env, [0], [0])
    ckpts = probe.checkpoints(tmp_path)
    assert [env for env, _ in ckpts] == list(range(6000, 13000, 1000))
    group = probe.window_at(ckpts, 10500, 3)
    assert [probe.STEP.fullmatch(d.name)[2] for d in group] == ["000000008000", "000000009000", "000000010000"]
    # Five checkpoints reach 10,000 env steps: a window of six has none.
    assert probe.window_at(ckpts, 10000, 5) is not None
    assert probe.window_at(ckpts, 10000, 6) is None


def test_keep_copies_every_checkpoint_and_the_config_until_the_runs_finish(tmp_path):
    runs, archive = tmp_path / "runs", tmp_path / "archive"
    for name in ("a", "b"):
        run = runs / "seed" / name
        checkpoint(run, 1000, 6000, [1], [1])
        (run / "checkpoints" / "step_000002000_env_000000007000.tmp-1").mkdir()
        (run / "config.toml").write_text(f"seed = '{name}'\n")
        (run / "summary.json").write_text("{}")
    probe.keep(argparse.Namespace(runs_dir=str(runs), into=str(archive), runs=2, poll=0.01))
    for name in ("a", "b"):
        kept = archive / name / "checkpoints"
        assert [d.name for d in kept.iterdir()] == ["step_000001000_env_000000006000"]
        assert (kept / "step_000001000_env_000000006000" / "params.safetensors").is_file()
        assert (archive / name / "config.toml").read_text() == f"seed = '{name}'\n"


@pytest.mark.parametrize("text", ["", "0,3", "three", "1,,3"])
def test_bad_windows_are_refused_with_what_was_expected_and_what_came(text):
    with pytest.raises(SystemExit, match=f"--windows: expected positive integers separated by commas, got '{text}'"):
        probe.positive_ints("--windows", text)


SCRIPT = pathlib.Path(__file__).resolve().parents[1] / "probe_averaged_policy.py"


@pytest.mark.parametrize("option", ["--every", "--episodes"])
def test_a_count_that_is_not_positive_is_refused_by_name(tmp_path, option):
    done = subprocess.run(
        [sys.executable, str(SCRIPT), "evaluate", str(tmp_path), option, "0"], capture_output=True, text=True
    )
    assert done.returncode == 2
    assert f"argument {option}: expected a positive integer, got '0'" in done.stderr


def test_a_failed_evaluation_stops_the_probe_with_the_command_that_failed(tmp_path):
    run = tmp_path / "run"
    checkpoint(run, 1000, 10000, [1], [1])
    (run / "config.toml").write_text("seed = 0\n")
    done = subprocess.run(
        [sys.executable, str(SCRIPT), "evaluate", str(tmp_path), "--windows", "1", "--agent", "false"],
        capture_output=True,
        text=True,
    )
    assert done.returncode == 1
    assert "false eval --checkpoint" in done.stderr
    assert "failed (exit 1)" in done.stderr
