"""The MuJoCo benchmark's table (scripts/bench_mujoco_table.py) on results files written
here: ours is paired with the peer of its own session, several results files are read as
one, and the stability check's criterion holds for positive and negative bests.

A front of one point (v, c) has the discounted hypervolume (v + 100)(c + 100) at
mo-halfcheetah's reference [-100, -100], so every expected figure is worked out beside it.
"""

from __future__ import annotations

import pathlib
import sys

import bench_mujoco_table as table_script
import pytest
from peers import results

TASK = "mo-halfcheetah-v5"


def run_rows(method: str, seed: int, points: list[tuple[int, float]], wall: float) -> list[dict]:
    """A two-objective run's rows: one-point fronts (v, 0) at each env step, the last final."""
    rows = []
    for n, (steps, v) in enumerate(points):
        kind = "final" if n == len(points) - 1 else "eval"
        front = [(v, 0.0)]
        rows.append(results.row(TASK, method, seed, kind, steps, front=front, front_discounted=front, wall_s=wall))
    return rows


def table(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture, *args: str) -> str:
    monkeypatch.setattr(sys, "argv", ["bench_mujoco_table.py", *args])
    table_script.main()
    return capsys.readouterr().out


@pytest.fixture
def two_files(tmp_path: pathlib.Path) -> tuple[pathlib.Path, pathlib.Path]:
    peers, levers = tmp_path / "results.csv", tmp_path / "levers.csv"
    # CAPQL: (0, 0) at 20k -> 10,000; (0, 0) at the end -> 10,000, in 1,000 s.
    results.append(peers, run_rows("CAPQL", 0, [(20000, 0.0), (40000, 0.0)], 1000.0), "s")
    # Ours, same session, another file: (-50, 0) -> 5,000 at 20k; (100, 0) -> 20,000 in 3,000 s.
    results.append(levers, run_rows("MO-MPO", 0, [(20000, -50.0), (40000, 100.0)], 3000.0), "s")
    return peers, levers


def row_of(out: str, method: str) -> list[str]:
    [line] = [line for line in out.splitlines() if line.startswith(f"| {TASK} | s | {method} |")]
    return [cell.strip() for cell in line.strip("|").split("|")]


def test_ours_is_paired_with_the_peer_of_its_session_across_files(monkeypatch, capsys, two_files):
    peers, levers = two_files
    alone = table(monkeypatch, capsys, "--results", str(peers))
    assert "MO-MPO" not in alone and row_of(alone, "CAPQL")[6] == "10,000"
    both = table(monkeypatch, capsys, "--results", f"{peers},{levers}")
    ours = row_of(both, "MO-MPO")
    # Columns: task, session, method, seeds, env steps, return, HV disc., HV undisc., wall,
    # then the ratios ours / peer: 20,000 / 10,000 = 2.00 (both HVs), 3,000 / 1,000 = 3.00.
    assert ours[6] == "20,000" and ours[8] == "3000"
    assert ours[9:12] == ["2.00", "2.00", "3.00"]
    # 40k is past half the run; 20,000 is its best, so it holds.
    assert ours[12] == "1/1"


def test_per_evaluation_lists_the_runs_of_every_file(monkeypatch, capsys, two_files):
    peers, levers = two_files
    out = table(monkeypatch, capsys, "--results", f"{peers},{levers}", "--per-evaluation")
    # A column per evaluation (20k), then the final row: HV in thousands, 5,000 -> 5.0 and
    # 20,000 -> **20.0**; undiscounted at [-100, -1000] in millions, (v + 100) * 1,000.
    assert "| mo-halfcheetah, 0 | MO-MPO, HV disc. (k) | 5.0 | **20.0** | 3000 |" in out
    assert "| mo-halfcheetah, 0 | MO-MPO, HV undisc. (M) | 0.05 | **0.20** |  |" in out
    assert "| mo-halfcheetah, 0 | CAPQL, HV disc. (k) | 10.0 | **10.0** | 1000 |" in out


def single_objective(returns: list[float]) -> list[dict]:
    """A HalfCheetah-v5 run's rows: evaluations every 10k, the last final."""
    n = len(returns)
    return [
        {"session": "s", **results.row("HalfCheetah-v5", "MO-MPO", 0, kind, 10000 * (i + 1), return_=v)}
        for i, v in enumerate(returns)
        for kind in ["final" if i == n - 1 else "eval"]
    ]


@pytest.mark.parametrize(
    ("returns", "why"),
    [
        # Best 200 by 20k; at 30k (past half of 40k) 150 < 200 - 0.2 * 200 = 160: falls.
        ([100.0, 200.0, 150.0, 170.0], "150.0 at 30000 env steps, best so far 200.0"),
        # 165 and 170 stay above 160: holds.
        ([100.0, 200.0, 165.0, 170.0], ""),
        # Negative best -150 allows -150 - 0.2 * 150 = -180: -179 holds, -181 falls.
        ([-300.0, -150.0, -179.0, -170.0], ""),
        ([-300.0, -150.0, -181.0, -170.0], "-181.0 at 30000 env steps, best so far -150.0"),
        # A fall in the first half does not count (20k is half of 40k, not past it).
        ([200.0, 100.0, 190.0, 200.0], ""),
    ],
)
def test_the_stability_check(returns, why):
    by_run = table_script.runs(single_objective(returns))
    [run] = by_run.values()
    assert table_script.unstable(run) == why


def test_per_evaluation_names_the_session_where_a_run_repeats(monkeypatch, capsys, two_files):
    peers, levers = two_files
    # Ours again, seed 0 in another session: (0, 0) -> 10,000 at 20k, (50, 0) -> 15,000.
    results.append(levers, run_rows("MO-MPO", 0, [(20000, 0.0), (40000, 50.0)], 2000.0), "t")
    out = table(monkeypatch, capsys, "--results", f"{peers},{levers}", "--per-evaluation")
    assert "| mo-halfcheetah, 0 | MO-MPO (`s`), HV disc. (k) | 5.0 | **20.0** | 3000 |" in out
    assert "| mo-halfcheetah, 0 | MO-MPO (`t`), HV disc. (k) | 10.0 | **15.0** | 2000 |" in out
    # CAPQL's seed 0 ran once: no session named.
    assert "| mo-halfcheetah, 0 | CAPQL, HV disc. (k) | 10.0 | **10.0** | 1000 |" in out


def test_a_session_named_with_a_method_gives_that_methods_runs_only(monkeypatch, capsys, two_files):
    peers, levers = two_files
    # Ours in session "t" (15,000 at the end), beside the peer of session "s" alone.
    results.append(levers, run_rows("MO-MPO", 0, [(20000, 0.0), (40000, 50.0)], 2000.0), "t")
    both = f"{peers},{levers}"
    out = table(monkeypatch, capsys, "--results", both, "--session", "t,s:CAPQL", "--per-evaluation")
    assert "| mo-halfcheetah, 0 | MO-MPO, HV disc. (k) | 10.0 | **15.0** | 2000 |" in out
    assert "| mo-halfcheetah, 0 | CAPQL, HV disc. (k) | 10.0 | **10.0** | 1000 |" in out
    assert "**20.0**" not in out  # ours of session "s"
    # A bare session id takes every method, whatever else names it.
    out = table(monkeypatch, capsys, "--results", both, "--session", "s:CAPQL,s", "--per-evaluation")
    assert "**20.0**" in out and "CAPQL, HV disc. (k)" in out


@pytest.mark.parametrize("entry", ["s:SB3", ":SAC", "s:"])
def test_a_session_entry_that_names_no_known_method_is_refused(monkeypatch, capsys, two_files, entry):
    peers, _ = two_files
    with pytest.raises(SystemExit):
        table(monkeypatch, capsys, "--results", str(peers), "--session", entry)
    err = capsys.readouterr().err
    assert "--session: expected ID or ID:METHOD with METHOD one of CAPQL, MO-MPO, SAC" in err
    assert f"got '{entry}'" in err
