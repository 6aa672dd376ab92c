#!/usr/bin/env python3
"""Would a weight-averaged policy hold what a run learned? A probe of finished runs.

    # while runs train with a short run.checkpoint_period (they keep only the last two
    # checkpoints), copy every checkpoint they write, replay left out:
    .venv/bin/python scripts/probe_averaged_policy.py keep RUNS_DIR --into ARCHIVE --runs 3

    # then, at each evaluation point, the policy's parameters averaged over the last W
    # checkpoints (W = 1: the policy itself), each evaluated with `agent eval`:
    .venv/bin/python scripts/probe_averaged_policy.py evaluate ARCHIVE \
        --windows 1,3,5,10 --episodes 20 --every 10000 > probe.csv

`keep` watches RUNS_DIR (any depth) for `checkpoints/step_*` folders and copies each
into ARCHIVE/RUN/ with the run's config.toml, until --runs runs have written their
summary.json. `evaluate` takes, for every multiple of --every env steps, the latest
archived checkpoint at or before it, averages every `policy/*` tensor over it and the
W - 1 before it (the rest of the learner is that checkpoint's), writes the result as a
checkpoint of ARCHIVE/RUN_wW/ and evaluates it with `agent eval --episodes N` (the
run's own evaluation seeds: the first 10 episodes are those of its `eval.csv`). It
prints one CSV row per run, point and window (stdout), then per run and window the
series and whether it holds by the benchmark's check (`bench_mujoco_table.unstable`;
stderr).
The training runs themselves are unchanged: this evaluates copies of their policies.
"""

from __future__ import annotations

import argparse
import csv
import json
import pathlib
import re
import shutil
import subprocess
import sys
import time

import numpy as np
from bench_mujoco_table import unstable
from safetensors.numpy import load_file, save_file

STEP = re.compile(r"step_(\d+)_env_(\d+)")


def positive_ints(option: str, text: str) -> list[int]:
    """`1,3,5` -> [1, 3, 5]; anything else exits naming the option."""
    try:
        values = [int(v) for v in text.split(",")]
    except ValueError:
        values = []
    if not values or min(values) < 1:
        sys.exit(f"{option}: expected positive integers separated by commas, got '{text}'")
    return values


def checkpoints(run: pathlib.Path) -> list[tuple[int, pathlib.Path]]:
    """A run's archived checkpoints as (env steps, folder), oldest first."""
    found = []
    for d in (run / "checkpoints").iterdir():
        m = STEP.fullmatch(d.name)
        if m and (d / "params.safetensors").is_file():
            found.append((int(m[1]), int(m[2]), d))
    return [(env, d) for _, env, d in sorted(found)]


def averaged(folders: list[pathlib.Path]) -> dict[str, np.ndarray]:
    """The last folder's parameters with every `policy/*` tensor the mean over all."""
    group = [load_file(str(f / "params.safetensors")) for f in folders]
    params = dict(group[-1])
    for name, value in params.items():
        if name.startswith("policy/"):
            params[name] = np.mean([g[name] for g in group], axis=0).astype(value.dtype)
    return params


def window_at(ckpts: list[tuple[int, pathlib.Path]], point: int, window: int) -> list[pathlib.Path] | None:
    """The `window` checkpoints ending at the latest at or before `point`; None if fewer."""
    upto = [d for env, d in ckpts if env <= point]
    return upto[-window:] if len(upto) >= window else None


def keep(args: argparse.Namespace) -> None:
    into = pathlib.Path(args.into)
    while True:
        # Whether the runs had finished is read before the copies' own listing, so that
        # the last pass copies what they wrote before their summary.json (one listing
        # for both would miss a final checkpoint written between it and the summary).
        runs = {p.parent.parent for p in pathlib.Path(args.runs_dir).glob("**/checkpoints/step_*")}
        finished = sum((r / "summary.json").exists() for r in runs) >= args.runs
        for step in pathlib.Path(args.runs_dir).glob("**/checkpoints/step_*"):
            out = into / step.parent.parent.name / "checkpoints" / step.name
            if STEP.fullmatch(step.name) and not (out / "params.safetensors").exists():
                tmp = out.with_name(out.name + ".tmp")
                try:
                    shutil.copytree(step, tmp, dirs_exist_ok=True)
                    shutil.copy(step.parent.parent / "config.toml", out.parent.parent / "config.toml")
                    tmp.rename(out)
                except (FileNotFoundError, shutil.Error):
                    # Pruned by its run while being copied (it keeps two): the next is kept.
                    shutil.rmtree(tmp, ignore_errors=True)
        if finished:
            return
        time.sleep(args.poll)


def evaluated(args: argparse.Namespace, checkpoint: pathlib.Path) -> tuple[float, list[str]]:
    """`agent eval` of one checkpoint: the mean return and each episode's length."""
    report = checkpoint / "probe-eval.json"
    cmd = [args.agent, "eval", "--checkpoint", str(checkpoint), "--episodes", str(args.episodes)]
    done = subprocess.run([*cmd, "--json", str(report)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    if done.returncode != 0:
        sys.exit(f"{' '.join(cmd)} failed (exit {done.returncode}):\n{done.stderr[-2000:]}")
    r = json.loads(report.read_text())
    return r["mean_return"][0], [str(e["length"]) for e in r["episodes"]]


def positive(text: str) -> int:
    """argparse type: a positive integer (argparse names the option in its error)."""
    if not text.isdigit() or int(text) < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got '{text}'")
    return int(text)


def evaluate(args: argparse.Namespace) -> None:
    windows = positive_ints("--windows", args.windows)
    out = csv.writer(sys.stdout)
    out.writerow(["run", "env_steps", "window", "mean_return", "episode_lengths"])
    series: dict[tuple[str, int], list[dict]] = {}
    for run in sorted(pathlib.Path(args.archive).iterdir()):
        if re.search(r"_w\d+$", run.name) or not (run / "checkpoints").is_dir():
            continue
        ckpts = checkpoints(run)
        last = ckpts[-1][0] if ckpts else 0
        for point in range(args.every, last + 1, args.every):
            for w in windows:
                group = window_at(ckpts, point, w)
                if group is None:
                    continue
                dest = run.with_name(f"{run.name}_w{w}") / "checkpoints" / group[-1].name
                shutil.copytree(group[-1], dest, dirs_exist_ok=True)
                shutil.copy(run / "config.toml", dest.parent.parent / "config.toml")
                save_file(averaged(group), str(dest / "params.safetensors"))
                mean, lengths = evaluated(args, dest)
                out.writerow([run.name, point, w, f"{mean:.1f}", "/".join(lengths)])
                sys.stdout.flush()
                series.setdefault((run.name, w), []).append({"task": "", "env_steps": point, "return": mean})
    for (run, w), rows in sorted(series.items()):
        fell = unstable(rows)
        values = " ".join(f"{r['return']:.0f}" for r in rows)
        print(f"{run} W={w}: {values}; {'holds' if not fell else 'does not hold: ' + fell}", file=sys.stderr)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    k = sub.add_parser("keep", help="copy every checkpoint the runs under RUNS_DIR write")
    k.add_argument("runs_dir")
    k.add_argument("--into", required=True, help="the archive folder")
    k.add_argument("--runs", type=positive, default=1, help="stop once this many runs have finished")
    k.add_argument("--poll", type=float, default=3.0, help="seconds between looks")
    e = sub.add_parser("evaluate", help="evaluate the averaged policies of an archive")
    e.add_argument("archive")
    e.add_argument("--windows", default="1,3,5,10", help="checkpoints averaged, comma-separated")
    e.add_argument("--episodes", type=positive, default=20)
    e.add_argument("--every", type=positive, default=10000, help="env steps between evaluation points")
    e.add_argument("--agent", default="target/release/agent")
    args = parser.parse_args()
    keep(args) if args.command == "keep" else evaluate(args)


if __name__ == "__main__":
    main()
