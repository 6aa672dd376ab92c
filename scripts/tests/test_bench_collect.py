"""The MuJoCo benchmark's results: the hypervolume its tables compare, and the collector
that turns one of our runs' folders into rows (scripts/bench_mujoco_collect.py).

The run folders here are written by hand in the agent's file formats (summary.json,
eval.csv, learner.jsonl), small enough that every expected figure is worked out in a
comment beside it.
"""

from __future__ import annotations

import csv
import json
import pathlib

import bench_mujoco_collect as collector
import pytest
from peers import results

TASK = "mo-halfcheetah-v5"  # discounted reference [-100, -100]


def test_hypervolume_is_the_staircase_area_and_ignores_dominated_and_outside_points():
    # (1,3), (2,2), (3,1) over (0,0): columns of width 1 and heights 1, 2, 3 -> 6.
    staircase = [(1.0, 3.0), (2.0, 2.0), (3.0, 1.0)]
    assert results.hypervolume(staircase, (0.0, 0.0)) == 6.0
    # (1,1) is dominated by (2,2); (-1,5) does not beat the reference's first objective.
    assert results.hypervolume(staircase + [(1.0, 1.0), (-1.0, 5.0)], (0.0, 0.0)) == 6.0
    assert results.hypervolume([], (0.0, 0.0)) == 0.0
    with pytest.raises(ValueError, match="2-objective"):
        results.hypervolume(staircase, (0.0, 0.0, 0.0))


def write_run(
    run: pathlib.Path, summary: dict, evals: list[dict], walls: list[tuple[int, float]], objectives: list[str]
) -> pathlib.Path:
    run.mkdir()
    (run / "summary.json").write_text(json.dumps({"objectives": objectives, "eval_discount": 0.99, **summary}))
    if evals:
        with open(run / "eval.csv", "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(evals[0]))
            w.writeheader()
            w.writerows(evals)
    lines = [
        json.dumps({"learner_step": i, "env_steps": steps, "wall_seconds": wall})
        for i, (steps, wall) in enumerate(walls)
    ]
    (run / "learner.jsonl").write_text("".join(line + "\n" for line in lines))
    return run


def point(steps: int, eps: float, v: float, c: float, dv: float, dc: float) -> dict:
    return {
        "env_steps": steps,
        "learner_steps": steps,
        "epsilon_objective_1": eps,
        "return_objective_0": v,
        "return_objective_1": c,
        "discounted_return_objective_0": dv,
        "discounted_return_objective_1": dc,
    }


@pytest.fixture
def stopped_conditioned_run(tmp_path: pathlib.Path) -> pathlib.Path:
    # Two evaluations of a two-point front. The clock restarts at 0 after 150 s (a resume
    # by an agent that did not keep it): the later records count 150 s more.
    evals = [
        point(100, 0.1, 0.0, 0.0, 0.0, 0.0),
        point(100, 1.0, 10.0, -500.0, 10.0, -50.0),
        point(200, 0.1, 0.0, 0.0, 0.0, 0.0),
        point(200, 1.0, 10.0, -500.0, 20.0, -50.0),
    ]
    walls = [(50, 40.0), (100, 90.0), (150, 150.0), (160, 5.0), (200, 60.0), (220, 70.0)]
    summary = {"interrupted": "SIGTERM", "env_steps": 230, "wall_seconds": 75.0, "eval_return": []}
    return write_run(tmp_path / "run", summary, evals, walls, ["objective_0", "objective_1"])


def test_a_stopped_run_is_refused_unless_asked_for(stopped_conditioned_run: pathlib.Path):
    with pytest.raises(SystemExit, match="interrupted .SIGTERM. at 230 env steps"):
        collector.collect(stopped_conditioned_run, TASK, 0, "reward", "")


def test_a_stopped_conditioned_run_gives_its_fronts_on_the_run_clock(stopped_conditioned_run: pathlib.Path):
    rows = collector.collect(stopped_conditioned_run, TASK, 3, "reward", "the settings", stopped=True)
    assert [(r["kind"], r["env_steps"]) for r in rows] == [("eval", 100), ("eval", 200)]
    # Over [-100, -100]: (0,0) alone is 100 x 100 = 10,000; (10,-50) adds its strip of
    # width 10 and height 50 beyond it: 10,500. At 200k (20,-50) adds 20 x 50: 11,000.
    assert [float(r["hv_discounted"]) for r in rows] == [10500.0, 11000.0]
    # Undiscounted over [-100, -1000]: 100 x 1000 = 100,000 plus 10 x 500 = 105,000.
    assert [float(r["hv_undiscounted"]) for r in rows] == [105000.0, 105000.0]
    # The last record at or before each evaluation: 90 s at 100; 150 + 60 s at 200.
    assert [float(r["wall_s"]) for r in rows] == [90.0, 210.0]
    assert {r["seed"] for r in rows} == {3} and {r["settings"] for r in rows} == {"the settings"}


def test_a_finished_run_ends_with_its_front_and_the_summed_wall(stopped_conditioned_run: pathlib.Path):
    run = stopped_conditioned_run
    summary = json.loads((run / "summary.json").read_text())
    summary.update(interrupted=None, front={"points": 2})
    (run / "summary.json").write_text(json.dumps(summary))
    (run / "front").mkdir()
    with open(run / "front" / "points.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(point(0, 0, 0, 0, 0, 0)))
        w.writeheader()
        w.writerow(point(230, 1.0, 30.0, -500.0, 30.0, -50.0))
    final = collector.collect(run, TASK, 0, "reward", "")[-1]
    assert (final["kind"], final["env_steps"]) == ("final", 230)
    # One point (30,-50): 130 x 50 = 6,500; its wall is the summary's 75 s after the
    # restart plus the 150 s before it.
    assert float(final["hv_discounted"]) == 6500.0
    assert float(final["wall_s"]) == 225.0


def test_a_single_objective_run_stopped_or_finished(tmp_path: pathlib.Path):
    evals = [{"env_steps": 10, "learner_steps": 10, "return_reward": -300.0}]
    walls = [(10, 3.0), (20, 6.0)]
    stopped = {"interrupted": "Ctrl-C", "env_steps": 20, "wall_seconds": 7.0, "eval_return": []}
    run = write_run(tmp_path / "stopped", stopped, evals, walls, ["reward"])
    rows = collector.collect(run, "HalfCheetah-v5", 0, "reward", "", stopped=True)
    assert [(r["kind"], float(r["return"]), float(r["wall_s"])) for r in rows] == [("eval", -300.0, 3.0)]
    finished = {"interrupted": None, "env_steps": 20, "wall_seconds": 7.0, "eval_return": [-200.0]}
    run = write_run(tmp_path / "finished", finished, evals, walls, ["reward"])
    rows = collector.collect(run, "HalfCheetah-v5", 0, "reward", "")
    assert [(r["kind"], float(r["return"]), float(r["wall_s"])) for r in rows] == [
        ("eval", -300.0, 3.0),
        ("final", -200.0, 7.0),
    ]
    with pytest.raises(SystemExit, match="--objective: expected one of the run's objectives"):
        collector.collect(run, "HalfCheetah-v5", 0, "task", "")


def test_rows_name_the_commit_the_session_pinned_else_the_checkouts(
    tmp_path: pathlib.Path, monkeypatch: pytest.MonkeyPatch
):
    row = results.row("HalfCheetah-v5", "MO-MPO", 0, "final", 100, return_=1.0)
    monkeypatch.delenv("BENCH_COMMIT", raising=False)
    checkout = results.commit()  # a 12-digit hash in a clone; "unknown" outside one
    assert checkout and checkout != "0123456789ab"
    monkeypatch.setenv("BENCH_COMMIT", "0123456789ab")
    path = tmp_path / "results.csv"
    results.append(path, [row], "s")
    monkeypatch.delenv("BENCH_COMMIT")
    results.append(path, [row], "s")
    assert [r["commit"] for r in results.read(path)] == ["0123456789ab", checkout]
