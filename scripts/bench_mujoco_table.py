#!/usr/bin/env python3
"""The MuJoCo benchmark's table, stability check and curves, from its results file.

    python scripts/bench_mujoco_table.py [--results docs/benchmarks/mujoco-results.csv[,FILE..]]
        [--session ID[:METHOD][,ID..]] [--tasks TASK[,TASK..]] [--plots DIR] [--ref-undiscounted TASK=X:Y]
        [--per-evaluation]

One markdown row per task, session and method: the seeds' medians (range) of the final
deterministic evaluation (return; on two-objective tasks the hypervolumes of the front,
discounted at γ = 0.99 and undiscounted) and of the wall time. On MO-MPO's row, ours/peer
ratios of those medians against SAC or CAPQL of the same session only (runs of one session
shared the machine at the same time); where a median is not positive, only "≥ peer" or
"< peer". `holds`: how many runs pass the stability check:
at every evaluation in the second half of the run (env steps > half the final's) the
score v is at least its best so far b minus 20% of |b| (v >= b - 0.2 |b|: 80% of b when
b > 0; for a negative best, at most 20% of its magnitude worse, e.g. b = -150 allows
-180). The score is the return, or the discounted hypervolume. The runs that fail are
listed below the table. --plots DIR draws DIR/mujoco-TASK.png per task: each run's
evaluations against env steps, coloured by method (none by default, so that a look at
another results file or a few sessions leaves the page's curves as they are). --per-evaluation
prints, instead of the summary, every run's evaluations: a table per set of evaluation
points, a row per task, seed and method (two-objective tasks: a row per hypervolume,
discounted in thousands and undiscounted in millions), the final evaluation in bold; where
the sessions read hold one task, seed and method twice, each of those rows names its session.
A session given as ID:METHOD contributes that method's runs only: e.g. SAC's runs of a
session whose MO-MPO runs used an earlier preset, beside the current preset's.
"""

from __future__ import annotations

import argparse
import pathlib
import statistics
from collections import Counter

from peers import results
from PIL import Image, ImageDraw, ImageFont
from plot_curves import COLOURS, label, nice_ticks

TASKS = ["HalfCheetah-v5", "Hopper-v5", "mo-halfcheetah-v5", "mo-hopper-2obj-v5"]
PEER = {"HalfCheetah-v5": "SAC", "Hopper-v5": "SAC", "mo-halfcheetah-v5": "CAPQL", "mo-hopper-2obj-v5": "CAPQL"}
OURS = "MO-MPO"


def score(r: dict) -> float:
    return float(r["return"] if r["task"] not in results.REFERENCES else r["hv_discounted"])


def runs(rows: list[dict]) -> dict[tuple, list[dict]]:
    """(task, session, method, seed) -> the finished run's rows by env steps, its final row last.
    A runner appends a run's rows together, ending in the final row; if a key ran twice
    in one session the later run wins."""
    out: dict[tuple, list[dict]] = {}
    pending: dict[tuple, list[dict]] = {}
    for r in rows:
        key = (r["task"], r["session"], r["method"], int(r["seed"]))
        pending.setdefault(key, []).append(r)
        if r["kind"] == "final":
            out[key] = sorted(pending.pop(key), key=lambda r: (int(r["env_steps"]), r["kind"] == "final"))
    return out


def values(rows: list[dict], column: str) -> list[float]:
    return [float(r[column]) for r in rows if r[column] != ""]


def unstable(run: list[dict]) -> str:
    """'' when the run holds, else where it first fell below the criterion."""
    total, best = int(run[-1]["env_steps"]), None
    for r in run:
        v = score(r)
        if best is not None and int(r["env_steps"]) > total / 2 and v < best - 0.2 * abs(best):
            return f"{v:.1f} at {r['env_steps']} env steps, best so far {best:.1f}"
        best = v if best is None else max(best, v)
    return ""


def median(values: list[float], fmt: str) -> str:
    if not values:
        return ""
    m = statistics.median(values)
    return fmt.format(m) + (f" ({fmt.format(min(values))} … {fmt.format(max(values))})" if len(values) > 1 else "")


def ratio(ours: list[float], peer: list[float]) -> str:
    """ours / peer of the medians; where either is not positive a ratio would mislead,
    so only whether ours reaches the peer's ("≥ peer" or "< peer")."""
    if not ours or not peer:
        return ""
    a, b = statistics.median(ours), statistics.median(peer)
    if a <= 0 or b <= 0:
        return "≥ peer" if a >= b else "< peer"
    return f"{a / b:.2f}"


def table(by_run: dict[tuple, list[dict]]) -> list[str]:
    groups: dict[tuple, list[list[dict]]] = {}
    for (task, session, method, _), run in sorted(by_run.items()):
        groups.setdefault((task, session, method), []).append(run)
    lines = [
        "| task | session | method | seeds | env steps | return | HV disc. | HV undisc. | wall s "
        "| ours/peer: return or HV disc. | HV undisc. | wall | holds |",
        "|" + "---|" * 13,
    ]
    order = sorted(groups, key=lambda k: (TASKS.index(k[0]) if k[0] in TASKS else 9, k[1], k[2] != OURS))
    for task, session, method in order:
        finals = [run[-1] for run in groups[task, session, method]]
        col = {c: values(finals, c) for c in ("return", "hv_discounted", "hv_undiscounted", "wall_s")}
        ratios = ["", "", ""]
        peer = [run[-1] for run in groups.get((task, session, PEER.get(task, "")), [])]
        if method == OURS and peer:
            pcol = {c: values(peer, c) for c in col}
            main = "return" if task not in results.REFERENCES else "hv_discounted"
            ratios = [ratio(col[main], pcol[main]), ratio(col["hv_undiscounted"], pcol["hv_undiscounted"])]
            ratios.append(ratio(col["wall_s"], pcol["wall_s"]))
        holds = sum(not unstable(run) for run in groups[task, session, method])
        cells = [task, session, method, ",".join(r["seed"] for r in finals)]
        cells.append("/".join(sorted({f"{int(r['env_steps']) / 1000:g}k" for r in finals})))
        cells += [median(col["return"], "{:.1f}"), median(col["hv_discounted"], "{:,.0f}")]
        cells += [median(col["hv_undiscounted"], "{:,.0f}"), median(col["wall_s"], "{:.0f}")]
        cells += [*ratios, f"{holds}/{len(finals)}"]
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def per_evaluation(by_run: dict[tuple, list[dict]]) -> list[str]:
    """Each run's evaluations, one table per set of evaluation points. Where one task,
    seed and method ran in several of the sessions read, each row names its session."""
    repeated = Counter((task, method, seed) for task, _, method, seed in by_run)
    tables: dict[tuple, list[tuple]] = {}
    for key, run in by_run.items():
        steps = tuple(int(r["env_steps"]) for r in run if r["kind"] == "eval")
        tables.setdefault(steps, []).append(key)
    lines: list[str] = []
    for steps, keys in sorted(tables.items()):
        head = [f"{s / 1000:g}k" for s in steps]
        lines += ["", "| task, seed | method | " + " | ".join(head) + " | final | wall s |"]
        lines.append("|" + "---|" * (len(steps) + 4))
        order = sorted(keys, key=lambda k: (TASKS.index(k[0]) if k[0] in TASKS else 9, k[3], k[2] != OURS, k[1]))
        for task, session, method, seed in order:
            run = by_run[task, session, method, seed]
            scores = [("", "return", 1.0)]
            if task in results.REFERENCES:
                scores = [(", HV disc. (k)", "hv_discounted", 1e3), (", HV undisc. (M)", "hv_undiscounted", 1e6)]
            for n, (suffix, column, unit) in enumerate(scores):
                fmt = "{:.0f}" if unit == 1.0 else ("{:.1f}" if unit == 1e3 else "{:.2f}")
                cell = lambda r: fmt.format(float(r[column]) / unit).replace("-", "−") if r[column] else ""  # noqa: E731
                who = method + (f" (`{session}`)" if repeated[task, method, seed] > 1 else "")
                cells = [f"{task.removesuffix('-v5')}, {seed}", who + suffix]
                cells += [cell(r) for r in run if r["kind"] == "eval"]
                cells += [f"**{cell(run[-1])}**", f"{float(run[-1]['wall_s']):.0f}" if n == 0 else ""]
                lines.append("| " + " | ".join(cells) + " |")
    return lines[1:]


def draw(task: str, task_runs: dict[tuple, list[dict]], out: pathlib.Path) -> None:
    """One panel per score (return; or HV discounted and undiscounted), a line per run."""
    columns = ["return"] if task not in results.REFERENCES else ["hv_discounted", "hv_undiscounted"]
    methods = sorted({k[2] for k in task_runs}, key=lambda m: m != OURS)
    pw, ph, ml, mt, mb = 420, 260, 70, 40, 50
    img = Image.new("RGB", (len(columns) * (pw + ml + 20) + ml, mt + ph + mb + 20), "white")
    d, font = ImageDraw.Draw(img), ImageFont.load_default()
    xmax = max(int(r["env_steps"]) for run in task_runs.values() for r in run)
    for j, column in enumerate(columns):
        x0 = ml + j * (pw + ml + 20)
        ys = [v for run in task_runs.values() for v in values(run, column)]
        lo, hi = min(ys), max(ys)
        lo, hi = lo - 0.05 * (hi - lo or 1), hi + 0.05 * (hi - lo or 1)

        def px(x: float, y: float, x0: int = x0, lo: float = lo, hi: float = hi) -> tuple[float, float]:
            return x0 + pw * x / xmax, mt + ph * (1 - (y - lo) / (hi - lo))

        for t in nice_ticks(lo, hi):
            d.line([(x0, px(0, t)[1]), (x0 + pw, px(0, t)[1])], fill=(230, 230, 230))
            d.text((x0 - 6, px(0, t)[1]), label(t), fill="black", font=font, anchor="rm")
        for t in nice_ticks(0, xmax):
            d.text((px(t, lo)[0], mt + ph + 6), f"{t / 1000:g}k", fill="black", font=font, anchor="mt")
        d.rectangle([x0, mt, x0 + pw, mt + ph], outline="black")
        refs = {r[column.replace("hv_", "ref_")] for run in task_runs.values() for r in run if column != "return"}
        title = f"{task}: {column}" + (f" at {', '.join(sorted(refs))}" if refs else "") + " (deterministic evaluation)"
        d.text((x0 + pw / 2, mt - 14), title, fill="black", font=font, anchor="mm")
        d.text((x0 + pw / 2, mt + ph + 22), "env steps", fill="black", font=font, anchor="mt")
        for (_, _, method, _), run in task_runs.items():
            line = [px(int(r["env_steps"]), float(r[column])) for r in run if r[column] != ""]
            colour = COLOURS[methods.index(method) % len(COLOURS)]
            if len(line) > 1:
                d.line(line, fill=colour, width=2)
            # A marker at each evaluation, so that a run evaluated once shows too.
            for x, y in line:
                d.ellipse([x - 3, y - 3, x + 3, y + 3], fill=colour)
    for k, method in enumerate(methods):
        x, y = ml + 10 + 120 * k, img.height - 14
        d.line([(x, y), (x + 18, y)], fill=COLOURS[k % len(COLOURS)], width=3)
        d.text((x + 22, y), method, fill="black", font=font, anchor="lm")
    out.parent.mkdir(parents=True, exist_ok=True)
    img.save(out, optimize=True)
    print(f"wrote {out}")


def sessions_wanted(spec: str) -> dict[str, set[str] | None]:
    """--session's value as session -> the methods read from it (None: every method)."""
    methods = sorted({OURS, *PEER.values()})
    wanted: dict[str, set[str] | None] = {}
    for entry in filter(None, spec.split(",")):
        session, colon, method = entry.partition(":")
        if not session or (colon and method not in methods):
            raise ValueError(f"expected ID or ID:METHOD with METHOD one of {', '.join(methods)}, got '{entry}'")
        known = wanted.get(session, set())
        # A bare ID reads every method, whatever other entries name for it.
        wanted[session] = None if not method or known is None else known | {method}
    return wanted


def kept(sessions: dict[str, set[str] | None], row: dict) -> bool:
    """Whether --session keeps this row: no session named, or the row's session with its method."""
    if not sessions:
        return True
    methods = sessions.get(row["session"], set())
    return methods is None or row["method"] in methods


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument(
        "--results",
        default="docs/benchmarks/mujoco-results.csv",
        help="results files (comma-separated), read as one: e.g. the peers' runs of the results file "
        "beside our lever runs of docs/benchmarks/mujoco-levers.csv",
    )
    ap.add_argument(
        "--session",
        default="",
        help="only these sessions' runs (comma-separated); ID:METHOD takes that method's runs of ID only",
    )
    ap.add_argument("--tasks", default="", help="only these tasks' runs (comma-separated)")
    ap.add_argument("--plots", default="", help="folder for the curves (none by default)")
    ap.add_argument("--per-evaluation", action="store_true", help="print every run's evaluations instead")
    ap.add_argument(
        "--ref-undiscounted",
        action="append",
        default=[],
        metavar="TASK=X:Y",
        help="recompute the undiscounted HV at this reference from the stored fronts",
    )
    args = ap.parse_args()
    try:
        sessions = sessions_wanted(args.session)
    except ValueError as e:
        ap.error(f"--session: {e}")
    tasks = set(filter(None, args.tasks.split(",")))
    if unknown := sorted(tasks - set(TASKS)):
        ap.error(f"--tasks: expected some of {', '.join(TASKS)}, got {', '.join(unknown)}")
    rows = [
        r
        for path in filter(None, args.results.split(","))
        for r in results.read(pathlib.Path(path))
        if kept(sessions, r) and (not tasks or r["task"] in tasks)
    ]
    for spec in args.ref_undiscounted:
        task, _, ref = spec.partition("=")
        point = tuple(float(v) for v in ref.split(":"))
        for r in rows:
            if r["task"] == task and r["front"]:
                r["hv_undiscounted"] = results.hypervolume(results.parse_points(r["front"]), point)
                r["ref_undiscounted"] = results.format_ref(point)
    by_run = runs(rows)
    if args.per_evaluation:
        print("\n".join(per_evaluation(by_run)))
        return
    refs = sorted({f"{r['task']} {r['ref_discounted']} / {r['ref_undiscounted']}" for r in rows if r["front"]})
    print("\n".join(table(by_run)))
    if refs:
        print("\nHV references (discounted / undiscounted): " + "; ".join(refs))
    for key, run in sorted(by_run.items()):
        if why := unstable(run):
            print(f"does not hold: {' '.join(map(str, key))}: {why}")
    for task in [t for t in TASKS if args.plots and any(k[0] == t for k in by_run)]:
        draw(task, {k: v for k, v in by_run.items() if k[0] == task}, pathlib.Path(args.plots) / f"mujoco-{task}.png")


if __name__ == "__main__":
    main()
