#!/usr/bin/env python3
"""Training-return curves of several runs of one task, one panel per objective.

    python scripts/plot_curves.py --out docs/results/reach-energy.png \
        --title "reach-energy, configs/mompo/small-continuous.toml" \
        --bucket 1000 RUN_DIR [RUN_DIR ...] [--labels "a,b,..."]

Each RUN_DIR is an agent run directory (or a folder holding exactly one), and its
episodes.csv is read: every training episode's undiscounted vector return and the env
step at which it ended. A curve point is the mean return of the episodes that ended in
one env-step bucket (bucket B: env steps in ((i - 1) B, i B]), plotted at i B. One line
per run (labelled by the seed in the directory name, or --labels), one panel per
objective. With --field critic_loss (or temperature, ...) the curve is instead the mean
of that learner.jsonl field over the records in each bucket.

Only the standard library and Pillow (which the venv has; matplotlib it has not) are
used, so the figure is drawn by hand: axes, ticks, a legend, and polylines.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import pathlib

from PIL import Image, ImageDraw, ImageFont

COLOURS = [(31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189), (140, 86, 75)]


def run_dir(path: pathlib.Path) -> pathlib.Path:
    """The run directory: `path` itself when it has episodes.csv, else its one child that has."""
    if (path / "episodes.csv").exists():
        return path
    found = sorted(p.parent for p in path.glob("*/episodes.csv"))
    if len(found) != 1:
        raise SystemExit(f"{path}: expected one run directory with episodes.csv, found {len(found)}")
    return found[0]


def curves(path: pathlib.Path, bucket: int) -> tuple[list[str], list[tuple[int, list[float]]]]:
    """Objective names and [(bucket end, mean return per objective)] of one run."""
    with open(path / "episodes.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    names = [k.removeprefix("return_") for k in rows[0] if k.startswith("return_")]
    sums: dict[int, list[float]] = {}
    counts: dict[int, int] = {}
    for r in rows:
        i = (int(r["env_steps"]) + bucket - 1) // bucket
        s = sums.setdefault(i, [0.0] * len(names))
        for j, n in enumerate(names):
            s[j] += float(r["return_" + n])
        counts[i] = counts.get(i, 0) + 1
    return names, [(i * bucket, [v / counts[i] for v in sums[i]]) for i in sorted(sums)]


def learner_curves(path: pathlib.Path, bucket: int, field: str) -> tuple[list[str], list[tuple[int, list[float]]]]:
    """Like curves(), for one per-objective field of learner.jsonl (e.g. critic_loss):
    the mean of the records whose env step falls in each bucket."""
    with open(path / "episodes.csv", newline="") as f:
        header = next(csv.reader(f))
    names = [k.removeprefix("return_") for k in header if k.startswith("return_")]
    sums: dict[int, list[float]] = {}
    counts: dict[int, int] = {}
    with open(path / "learner.jsonl") as f:
        for line in f:
            r = json.loads(line)
            i = (int(r["env_steps"]) + bucket - 1) // bucket
            s = sums.setdefault(i, [0.0] * len(r[field]))
            for j, v in enumerate(r[field]):
                s[j] += float(v)
            counts[i] = counts.get(i, 0) + 1
    n = len(next(iter(sums.values())))
    if n != len(names):
        names = [str(j) for j in range(n)]
    return names, [(i * bucket, [v / counts[i] for v in sums[i]]) for i in sorted(sums)]


def nice_ticks(lo: float, hi: float, n: int = 5) -> list[float]:
    """About n round tick values covering [lo, hi]."""
    if hi <= lo:
        hi = lo + 1.0
    raw = (hi - lo) / n
    mag = 10 ** math.floor(math.log10(raw))
    step = min((m * mag for m in (1, 2, 2.5, 5, 10) if m * mag >= raw), default=10 * mag)
    first = math.ceil(lo / step) * step
    return [first + k * step for k in range(int((hi - first) / step + 1e-9) + 1)]


def label(v: float) -> str:
    """A tick value, short but distinct from its neighbours: ticks are round multiples
    of their step, so `g`'s significant digits keep them apart (one digit of an
    exponent form made 64,000 and 64,500 both "6e+04")."""
    if abs(v) >= 1e6:
        return f"{v / 1e6:g}M"
    if abs(v) >= 1e4:
        return f"{v / 1e3:g}k"
    return f"{round(v, 12):g}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", nargs="+", type=pathlib.Path)
    ap.add_argument("--out", type=pathlib.Path, required=True)
    ap.add_argument("--title", default="")
    ap.add_argument("--bucket", type=int, default=1000, help="env steps per curve point")
    ap.add_argument("--field", default="", help="plot this learner.jsonl field (e.g. critic_loss) instead of returns")
    ap.add_argument("--logy", action="store_true", help="logarithmic y axis (positive values only)")
    ap.add_argument("--names", default="", help="comma-separated panel names (default: the objective names)")
    ap.add_argument("--labels", default="", help="comma-separated legend labels (default: the seeds)")
    args = ap.parse_args()
    labels = args.labels.split(",") if args.labels else []
    if labels and len(labels) != len(args.runs):
        raise SystemExit(f"--labels: {len(labels)} labels for {len(args.runs)} runs")

    runs = []
    for p in args.runs:
        d = run_dir(p)
        parts = d.name.split("__")
        seed = parts[2] if len(parts) >= 3 else d.name
        names, pts = learner_curves(d, args.bucket, args.field) if args.field else curves(d, args.bucket)
        runs.append((labels[len(runs)] if labels else f"seed {seed}", names, pts))
    names = runs[0][1]
    if args.names:
        names = [f"{n} ({o})" for n, o in zip(args.names.split(","), names, strict=True)]
    xmax = max(pts[-1][0] for _, _, pts in runs)

    pw, ph, ml, mr, mt, mb = 420, 280, 62, 14, 46, 44
    width, height = ml + len(names) * (pw + ml + mr), mt + ph + mb + 24
    img = Image.new("RGB", (width, height), "white")
    d = ImageDraw.Draw(img)
    font = ImageFont.load_default()
    d.text((ml, 8), args.title, fill="black", font=font)
    for j, name in enumerate(names):
        x0 = ml + j * (pw + ml + mr)
        ys = [v[j] for _, _, pts in runs for _, v in pts]
        if args.logy:
            ys = [math.log10(max(y, 1e-12)) for y in ys]
        lo, hi = min(ys), max(ys)
        pad = 0.05 * (hi - lo or 1.0)
        lo, hi = lo - pad, hi + pad
        ty = (lambda y: math.log10(max(y, 1e-12))) if args.logy else (lambda y: y)

        def px(x: float, y: float, x0: int = x0, lo: float = lo, hi: float = hi) -> tuple[float, float]:
            return x0 + pw * x / xmax, mt + ph * (1 - (y - lo) / (hi - lo))

        yticks = range(math.ceil(lo), math.floor(hi) + 1) if args.logy else nice_ticks(lo, hi)
        for t in yticks:
            _, y = px(0, t)
            d.line([(x0, y), (x0 + pw, y)], fill=(230, 230, 230))
            d.text((x0 - 6, y), f"1e{t}" if args.logy else label(t), fill="black", font=font, anchor="rm")
        for t in nice_ticks(0, xmax):
            x, _ = px(t, lo)
            d.line([(x, mt), (x, mt + ph)], fill=(230, 230, 230))
            d.text((x, mt + ph + 6), label(t) if t < 1000 else f"{t / 1000:g}k", fill="black", font=font, anchor="mt")
        d.rectangle([x0, mt, x0 + pw, mt + ph], outline="black")
        d.text(
            (x0 + pw / 2, mt - 14), f"{args.field or 'training return'}: {name}", fill="black", font=font, anchor="mm"
        )
        d.text(
            (x0 + pw / 2, mt + ph + 24),
            f"env steps (mean of {'records' if args.field else 'episodes ending'} in each {args.bucket}-step bucket)",
            fill="black",
            font=font,
            anchor="mt",
        )
        for k, (_, _, pts) in enumerate(runs):
            line = [px(x, ty(v[j])) for x, v in pts]
            d.line(line, fill=COLOURS[k % len(COLOURS)], width=2)
    for k, (lab, _, _) in enumerate(runs):
        x = ml + 10 + sum(30 + 6 * len(lab) for lab, _, _ in runs[:k])
        y = height - 14
        d.line([(x, y), (x + 18, y)], fill=COLOURS[k % len(COLOURS)], width=3)
        d.text((x + 22, y), lab, fill="black", font=font, anchor="lm")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    img.save(args.out, optimize=True)
    print(f"wrote {args.out} ({args.out.stat().st_size} bytes)")


if __name__ == "__main__":
    main()
