#!/usr/bin/env python3
"""The long-run table of scripts/bench_hold.sh, from its runs folder.

    python scripts/bench_hold_table.py RUNS

RUNS holds one folder per seed (`seed-S/<run>/`), each a finished `agent train` run with
periodic evaluations (`eval.csv`) and `eval_final.json`, the `agent eval --json` report
of its final policy on more episodes. One markdown row per seed: the env steps at which
training first counted as solved (`run.solve_threshold`), the deterministic evaluations
of the objective the threshold names (else the first), the final evaluation as the run
made it and on the report's episodes with its standard error, and whether the run holds
by the MuJoCo benchmark's criterion (`bench_mujoco_table.unstable`: in the second half,
no evaluation below its best so far minus 20% of the best's magnitude). Then the counts
over the seeds.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import pathlib
import statistics

from bench_mujoco_table import unstable


def run_dirs(runs: pathlib.Path) -> dict[int, pathlib.Path]:
    """Seed -> its finished run folder (the newest if a seed ran twice)."""
    found = {}
    for seed_dir in runs.glob("seed-*"):
        dirs = sorted(p for p in seed_dir.iterdir() if (p / "summary.json").is_file())
        if dirs:
            found[int(seed_dir.name.removeprefix("seed-"))] = dirs[-1]
    return dict(sorted(found.items()))


def seed_row(seed: int, run: pathlib.Path) -> dict:
    summary = json.loads((run / "summary.json").read_text())
    threshold = summary.get("solve_threshold") or {}
    name = next(iter(threshold), summary["objectives"][0])
    k = summary["objectives"].index(name)
    with open(run / "eval.csv", newline="") as f:
        evals = [(int(r["env_steps"]), float(r[f"return_{name}"])) for r in csv.DictReader(f)]
    final = json.loads((run / "eval_final.json").read_text())
    returns = [e["episode_return"][k] for e in final["episodes"]]
    own = [e["episode_return"][k] for e in summary["eval_episodes"]]
    rows = [{"task": "hold", "env_steps": s, "return": v} for s, v in evals]
    return {
        "seed": seed,
        "objective": name,
        "threshold": threshold.get(name),
        "solved": summary["solved"]["env_steps"] if summary.get("solved") else None,
        "evals": evals,
        "own": statistics.fmean(own),
        "own_n": len(own),
        "final": statistics.fmean(returns),
        "final_se": statistics.stdev(returns) / math.sqrt(len(returns)) if len(returns) > 1 else float("nan"),
        "final_n": len(returns),
        "unstable": unstable(rows) if rows else "no evaluations",
    }


def table(rows: list[dict]) -> list[str]:
    every = rows[0]["evals"]
    span = f"{every[0][0]:,} … {every[-1][0]:,}" if every else ""
    lines = [
        f"| seed | solved at (env steps) | {rows[0]['objective']}: evaluations {span} "
        f"| final ({rows[0]['own_n']} episodes) | final ({rows[0]['final_n']} episodes) ± s.e. | holds |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        solved = f"{r['solved']:,}" if r["solved"] is not None else "not solved"
        evals = " ".join(f"{v:.0f}" for _, v in r["evals"])
        holds = "yes" if not r["unstable"] else f"no: {r['unstable']}"
        lines.append(
            f"| {r['seed']} | {solved} | {evals} | {r['own']:.1f} | {r['final']:.1f} ± {r['final_se']:.1f} | {holds} |"
        )
    return lines


def summary(rows: list[dict]) -> list[str]:
    n = len(rows)
    solved = [r["solved"] for r in rows if r["solved"] is not None]
    # Unsolved runs count as infinitely slow, so the median is over all N runs.
    times = sorted(solved) + [math.inf] * (n - len(solved))
    median = statistics.median(times)
    lines = [
        f"solved: {len(solved)} of {n}; median time to solve "
        + (f"{median:,.0f} env steps ({min(times):,} … {max(times):,})" if median < math.inf else "not solved")
    ]
    threshold = rows[0]["threshold"]
    if threshold is not None:
        name = rows[0]["objective"]
        at_final = sum(r["final"] >= threshold for r in rows)
        at_own = sum(r["own"] >= threshold for r in rows)
        lines.append(
            f"final {name} >= {threshold:g}: {at_final} of {n} on {rows[0]['final_n']} episodes "
            f"({at_own} of {n} on the run's own {rows[0]['own_n']})"
        )
    lines.append(f"holds: {sum(not r['unstable'] for r in rows)} of {n}")
    lines += [f"  seed {r['seed']} does not hold: {r['unstable']}" for r in rows if r["unstable"]]
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", type=pathlib.Path, help="bench_hold.sh's runs folder (seed-S/<run>/)")
    args = parser.parse_args()
    rows = [seed_row(seed, run) for seed, run in run_dirs(args.runs).items()]
    if not rows:
        raise SystemExit(f"{args.runs}: no finished runs (seed-S/<run>/summary.json)")
    print("\n".join(table(rows) + [""] + summary(rows)))


if __name__ == "__main__":
    main()
