"""The MuJoCo benchmark's results file: one row per evaluation of a run, and one final row.

Shared by the peers' runners (sac.py, capql.py; in .venv-peers) and by the collector of
our runs and the table printer (in .venv), so it uses the standard library only.

A row: `session, date, commit, machine, load` (where and when it was measured: ratios
only pair runs of one session), `task, method, seed, kind` (`eval` for a periodic
evaluation, `final` for the run's end), `env_steps`, `return` (single-objective tasks:
mean undiscounted return of the deterministic policy), for two-objective tasks the front
(one point per evaluated preference: mean undiscounted and discounted returns, `x:y;...`)
and its hypervolumes at the stated references, `wall_s` (seconds since the run started,
evaluations included), `eval_s` (of which evaluating, where the runner knows it) and
`settings` (what ran). `load` is the machine's 15-minute load average when the run
ended (this machine's 2 cores are shared).
"""

from __future__ import annotations

import argparse
import csv
import datetime
import os
import pathlib
import platform
import subprocess
import time

COLUMNS = [
    "session",
    "date",
    "commit",
    "machine",
    "load",
    "task",
    "method",
    "seed",
    "kind",
    "env_steps",
    "return",
    "hv_discounted",
    "hv_undiscounted",
    "ref_discounted",
    "ref_undiscounted",
    "front",
    "front_discounted",
    "wall_s",
    "eval_s",
    "settings",
]

# Hypervolume references per two-objective task. Discounted (γ = 0.99): MORL-Baselines'
# benchmark point for CAPQL on mo-halfcheetah and mo-hopper-2d (its issue 43). Undiscounted:
# ours. mo-halfcheetah's objectives are [x velocity, -Σa²] per step; -1000 on control is
# the discounted point's per-step level (-1 per step) over a 1000-step episode, and -100
# on velocity keeps the field's "not running backwards". Both of mo-hopper-2obj's
# objectives carry the +1 healthy reward, so its returns are rarely negative and the
# field's point serves as it is.
REFERENCES = {
    "mo-halfcheetah-v5": {"discounted": (-100.0, -100.0), "undiscounted": (-100.0, -1000.0)},
    "mo-hopper-2obj-v5": {"discounted": (-100.0, -100.0), "undiscounted": (-100.0, -100.0)},
}
GAMMA = 0.99

Point = tuple[float, ...]


def hypervolume(points: list[Point], ref: Point) -> float:
    """Area dominated by `points` (both objectives maximised) and bounded by `ref`.

    Points that do not strictly beat `ref` in both objectives add nothing, as in pymoo's
    HV (which MORL-Baselines calls; capql.py checks the two agree on every front)."""
    if len(ref) != 2:
        raise ValueError(f"hypervolume: expected a 2-objective reference, got {ref}")
    inside = sorted((p for p in points if p[0] > ref[0] and p[1] > ref[1]), key=lambda p: -p[0])
    area, top = 0.0, ref[1]
    for x, y in inside:
        if y > top:
            area += (x - ref[0]) * (y - top)
            top = y
    return area


def format_points(points: list[Point]) -> str:
    return ";".join(":".join(f"{v:.8g}" for v in p) for p in points)


def parse_points(text: str) -> list[Point]:
    return [tuple(float(v) for v in p.split(":")) for p in text.split(";") if p]


def format_ref(ref: Point) -> str:
    return ":".join(f"{v:g}" for v in ref)


def row(task: str, method: str, seed: int, kind: str, env_steps: int, **fields: object) -> dict:
    """One row; `front` and `front_discounted` (lists of points) get their hypervolumes
    at the task's REFERENCES; `return_`, `wall_s`, `eval_s`, `settings` as given."""
    out: dict = {"task": task, "method": method, "seed": seed, "kind": kind, "env_steps": env_steps}
    out["return"] = fields.pop("return_", "")
    for name, key in (("front", "undiscounted"), ("front_discounted", "discounted")):
        points = fields.pop(name, None)
        if points is not None:
            ref = REFERENCES[task][key]
            out[name] = format_points(points)
            out[f"hv_{key}"] = hypervolume(points, ref)
            out[f"ref_{key}"] = format_ref(ref)
    out.update(fields)
    out = {k: f"{v:.8g}" if isinstance(v, float) else v for k, v in out.items()}
    unknown = set(out) - set(COLUMNS)
    if unknown:
        raise ValueError(f"row: unknown fields {sorted(unknown)}; the columns are {COLUMNS}")
    return out


def machine() -> str:
    """CPU model and core count, e.g. `AMD EPYC x2`."""
    model = platform.processor() or platform.machine()
    try:
        for line in pathlib.Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{model} x{os.cpu_count()}"


def commit() -> str:
    """The checkout's commit, `+dirty` when tracked files differ from it; or `BENCH_COMMIT`
    when the caller set it: scripts/bench_mujoco.sh takes the commit once, as it builds,
    so that a commit made while its runs train does not label code they did not run."""
    pinned = os.environ.get("BENCH_COMMIT", "")
    if pinned:
        return pinned
    root = pathlib.Path(__file__).resolve().parents[2]

    def git(*args: str) -> str:
        return subprocess.run(["git", "-C", str(root), *args], capture_output=True, text=True).stdout.strip()

    head = git("rev-parse", "--short=12", "HEAD") or "unknown"
    return head + ("+dirty" if git("status", "--porcelain", "--untracked-files=no") else "")


def append(path: pathlib.Path, rows: list[dict], session: str) -> None:
    """Append a finished run's rows in one write (a header first when the file is new)."""
    stamp = {
        "session": session,
        "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "commit": commit(),
        "machine": machine(),
        "load": f"{os.getloadavg()[2]:.1f}",
    }
    path.parent.mkdir(parents=True, exist_ok=True)
    new = not path.exists() or path.stat().st_size == 0
    with open(path, "a", newline="") as f:
        w = csv.DictWriter(f, fieldnames=COLUMNS)
        if new:
            w.writeheader()
        w.writerows({**stamp, **r} for r in rows)


def read(path: pathlib.Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def parse_run_args(ap: argparse.ArgumentParser, tasks: list[str] | None, steps: int, eval_every: int):
    """A peer runner's arguments: its own (already on `ap`) and the ones every runner takes."""
    ap.add_argument("--task", required=True, choices=tasks, help="the Gymnasium or MO-Gymnasium env id")
    ap.add_argument("--seed", type=int, required=True)
    ap.add_argument("--steps", type=int, default=steps, help="env steps to train")
    ap.add_argument("--eval-every", type=int, default=eval_every, help="env steps between evaluations (0: final only)")
    ap.add_argument("--threads", type=int, default=1, help="torch.set_num_threads")
    ap.add_argument("--results", type=pathlib.Path, required=True, help="results file to append to")
    ap.add_argument("--session", required=True, help="the session the run belongs to")
    args = ap.parse_args()
    for name, least in (("seed", 0), ("steps", 1), ("eval_every", 0), ("threads", 1)):
        if getattr(args, name) < least:
            ap.error(f"--{name.replace('_', '-')}: expected at least {least}, got {getattr(args, name)}")
    return args


class Clock:
    """Seconds since the run started, and of them the seconds spent evaluating."""

    def __init__(self) -> None:
        self.start = time.perf_counter()
        self.eval_s = 0.0

    def wall(self) -> float:
        return time.perf_counter() - self.start
