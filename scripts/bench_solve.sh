#!/usr/bin/env bash
# Time-to-solve of the pendulum preset: trains it N times (seeds 0..N-1) against one
# local env_server, one run at a time, and prints per seed and as median / range the
# env steps and wall seconds at which the mean of the last 10 training episodes first
# reached run.solve_threshold (task >= -200 in the preset). Each run stops once solved
# (run.stop_on_solve), or at run.total_env_steps.
#
#   scripts/bench_solve.sh [N] [--config FILE] [--set PATH=VALUE ...]
#   scripts/bench_solve.sh 5                                        # the preset as shipped
#   scripts/bench_solve.sh 5 --set learner.objectives.1.epsilon=0.0 # action_norm switched off
#
# Extra arguments go to every `agent train` (see `agent train --help`). Runs are written
# under a temporary directory, removed at the end.
set -euo pipefail
cd "$(dirname "$0")/.."
n=5
if [[ $# -gt 0 && $1 =~ ^[0-9]+$ ]]; then n=$1; shift; fi
config=configs/mompo/pendulum.toml
args=()
while [[ $# -gt 0 ]]; do
  case $1 in
    --config) config=$2; shift 2 ;;
    *) args+=("$1"); shift ;;
  esac
done
scripts/setup.sh
cargo build --locked --release -p agent --bin agent
export MUJOCO_GL=${MUJOCO_GL:-disable}
work=$(mktemp -d)
server_log=$work/server.log
source scripts/lib/env_server.sh
trap 'stop_env_server; rm -rf "$work"' EXIT
start_env_server "$server_log"
echo "==> $n runs of $config ${args[*]:-} against $address"
for seed in $(seq 0 $((n - 1))); do
  target/release/agent train --config "$config" --server "$address" --set "seed=$seed" --set run.stop_on_solve=true \
    --set "run.runs_dir=\"$work/runs\"" "${args[@]}" >"$work/train-$seed.log" 2>&1 \
    || { tail -20 "$work/train-$seed.log"; exit 1; }
  summary=$(ls -d "$work"/runs/*__"$seed"__*/ | tail -1)summary.json
  cp "$summary" "$work/summary-$seed.json"
  .venv/bin/python - "$work/summary-$seed.json" "$seed" <<'PY'
import json, sys
s = json.load(open(sys.argv[1]))
solved = s["solved"]
rule = ", ".join(f"{k} >= {v}" for k, v in s["solve_threshold"].items()) or "no run.solve_threshold"
if solved:
    print(f"  seed {sys.argv[2]}: solved ({rule}) at {solved['env_steps']} env steps, {solved['wall_seconds']:.1f} s"
          f"  (run: {s['env_steps']} env steps, {s['wall_seconds']:.1f} s; eval {s['eval_return'][0]:.1f})")
else:
    print(f"  seed {sys.argv[2]}: not solved ({rule}) within {s['env_steps']} env steps, {s['wall_seconds']:.1f} s")
PY
done
.venv/bin/python - "$work" "$n" <<'PY'
import json, statistics, sys
work, n = sys.argv[1], int(sys.argv[2])
runs = [json.load(open(f"{work}/summary-{i}.json")) for i in range(n)]
print(f"solved {sum(1 for r in runs if r['solved'])} of {n}")
# Unsolved runs count as infinitely slow, so the median is over all N runs.
inf = float("inf")
for key, unit in (("env_steps", "env steps"), ("wall_seconds", "seconds")):
    v = [r["solved"][key] if r["solved"] else inf for r in runs]
    show = lambda x: "not solved" if x == inf else f"{x:.1f}"
    print(f"  {unit:>9} to solve: median {show(statistics.median(v))}  range [{show(min(v))}, {show(max(v))}]")
PY
