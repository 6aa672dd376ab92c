#!/usr/bin/env python3
"""Append one finished `agent train` run of the MuJoCo benchmark to its results file.

    python scripts/bench_mujoco_collect.py RUN_DIR --task HalfCheetah-v5 --seed 0 \
        --results docs/benchmarks/mujoco-results.csv --session ID --settings "..."

Rows as scripts/peers/results.py describes. Periodic evaluations come from the run's
eval.csv (`run.eval_period`; none when the run had no such evaluations): on a
single-objective task the mean return of `--objective`; on a two-objective task (an
ε-conditioned run: one row per grid point per evaluation; a fixed-ε run: one row, a
one-point front) the front of the points' mean returns, undiscounted and discounted. The
final row is the run's end: summary.json's evaluation, or for a conditioned run its front
(front/points.csv). wall_s is the agent's own training wall time: summary.json's for the
final row; for a periodic row, learner.jsonl's at its last record at or before that env
step (records come every `run.log_period` learner steps). Agents before the run clock
was kept in checkpoints restarted it at 0 on each resume; such a run's legs are added up
here. A run stopped before its budget (summary.json's `interrupted`) is refused,
unless `--stopped`: then its periodic evaluations are appended alone, with no final row
(a run resumed later and collected again adds them once more: use a session of its own).
"""

from __future__ import annotations

import argparse
import csv
import json
import pathlib

from peers import results


def read_csv(path: pathlib.Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def points(rows: list[dict], prefix: str, objectives: list[str]) -> list[tuple[float, ...]]:
    return [tuple(float(r[f"{prefix}{o}"]) for o in objectives) for r in rows]


def training_clock(run: pathlib.Path) -> tuple[list[tuple[int, float]], float]:
    """learner.jsonl's (env steps, wall seconds), the legs of an older agent's resumes
    added up; and the seconds those earlier legs add to its summary's wall time."""
    path = run / "learner.jsonl"
    marks: list[tuple[int, float]] = []
    earlier, last = 0.0, 0.0
    for line in path.read_text().splitlines() if path.exists() else []:
        record = json.loads(line)
        wall = float(record["wall_seconds"])
        if wall < last:  # a resume by an agent that restarted its clock
            earlier += last
        last = wall
        marks.append((int(record["env_steps"]), earlier + wall))
    return marks, earlier


def wall_at(marks: list[tuple[int, float]], steps: int) -> dict:
    """wall_s of the last record at or before `steps` env steps, if any."""
    before = [wall for at, wall in marks if at <= steps]
    return {"wall_s": round(before[-1], 3)} if before else {}


def collect(
    run: pathlib.Path, task: str, seed: int, objective: str, settings: str, stopped: bool = False
) -> list[dict]:
    summary = json.loads((run / "summary.json").read_text())
    finished = not summary.get("interrupted")
    if not finished and not stopped:
        raise SystemExit(
            f"{run}: the run was interrupted ({summary['interrupted']}) at {summary['env_steps']} env steps; "
            "not a finished run (--stopped appends its periodic evaluations alone)"
        )
    names = summary["objectives"]
    evals = read_csv(run / "eval.csv") if (run / "eval.csv").exists() else []
    common = {"settings": settings}
    marks, earlier = training_clock(run)
    wall = {"wall_s": summary["wall_seconds"] + earlier}
    if task not in results.REFERENCES:
        if objective not in names:
            raise SystemExit(f"--objective: expected one of the run's objectives {names}, got {objective!r}")
        rows = [
            results.row(
                task,
                "MO-MPO",
                seed,
                "eval",
                int(r["env_steps"]),
                return_=float(r[f"return_{objective}"]),
                **common,
                **wall_at(marks, int(r["env_steps"])),
            )
            for r in evals
        ]
        if not finished:
            return rows  # a stopped run's summary has no final evaluation
        ret = summary["eval_return"][names.index(objective)]
        return rows + [results.row(task, "MO-MPO", seed, "final", summary["env_steps"], return_=ret, **common, **wall)]

    if len(names) != 2:
        raise SystemExit(f"{run}: expected the two objectives of {task}, got {names}")
    if summary["eval_discount"] != results.GAMMA:
        raise SystemExit(f"{run}: discounted returns use γ = {summary['eval_discount']}; the benchmark's is 0.99")
    by_step: dict[int, list[dict]] = {}
    for r in evals:
        by_step.setdefault(int(r["env_steps"]), []).append(r)

    def row(kind: str, steps: int, rs: list[dict], **extra: object) -> dict:
        front, discounted = points(rs, "return_", names), points(rs, "discounted_return_", names)
        return results.row(task, "MO-MPO", seed, kind, steps, front=front, front_discounted=discounted, **extra)

    rows = [row("eval", steps, rs, **common, **wall_at(marks, steps)) for steps, rs in sorted(by_step.items())]
    if not finished:
        return rows
    if summary.get("front") is not None:
        end = read_csv(run / "front" / "points.csv")
    else:
        # A fixed-ε run is one preference: its front is its one evaluated point.
        end = [
            {f"return_{o}": v for o, v in zip(names, summary["eval_return"])}
            | {f"discounted_return_{o}": v for o, v in zip(names, summary["eval_discounted_return"])}
        ]
    return rows + [row("final", summary["env_steps"], end, **common, **wall)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("run", type=pathlib.Path, help="the run directory (holds summary.json)")
    ap.add_argument("--task", required=True)
    ap.add_argument("--seed", type=int, required=True)
    ap.add_argument("--objective", default="reward", help="single-objective tasks: the objective compared with SAC")
    ap.add_argument("--settings", default="", help="what ran (config and overrides)")
    ap.add_argument("--results", type=pathlib.Path, required=True)
    ap.add_argument("--session", required=True)
    ap.add_argument(
        "--stopped", action="store_true", help="a run stopped before its budget: append its periodic evaluations alone"
    )
    args = ap.parse_args()
    rows = collect(args.run, args.task, args.seed, args.objective, args.settings, args.stopped)
    if not rows:
        raise SystemExit(f"{args.run}: the run was stopped before its first periodic evaluation; nothing to append")
    results.append(args.results, rows, args.session)
    last = rows[-1]
    score = last["return"] or f"HV {last['hv_discounted']} discounted, {last['hv_undiscounted']} undiscounted"
    wall = f"{last['wall_s']} s" if last["kind"] == "final" else "stopped there (periodic evaluations only)"
    print(f"MO-MPO {args.task} seed {args.seed}: {score} at {last['env_steps']} env steps, {wall}")


if __name__ == "__main__":
    main()
