#!/usr/bin/env bash
# What each way of placing env servers costs, end to end: `agent train` on one preset
# (default: configs/mompo/dst.toml, 3 actors) with
#   1. the local env_server the agent starts itself (the default),
#   2. N env_servers on loopback, found through `--server file:PATH` (the path that
#      `dns:` names and the Ray launcher take: one pinned channel per address),
#   3. N env_servers as Ray actors on a local Ray (`python -m env_server.tools.ray`).
# Env steps/s and learner steps/s are taken after the replay warm-up
# (scripts/lib/train_rates.py). On one machine every variant shares the same cores, so
# this measures overhead, not added capacity.
#
#   scripts/bench_scaling.sh [CONFIG [ENV_STEPS [N]]]
set -euo pipefail
cd "$(dirname "$0")/.."
config=${1:-configs/mompo/dst.toml}
steps=${2:-12000}
n=${3:-3}
scripts/setup.sh
cargo build --locked --release -p agent --bin agent
export MUJOCO_GL=${MUJOCO_GL:-disable} RAY_USAGE_STATS_ENABLED=0
work=$(mktemp -d)
pids=()
cleanup() {
  for pid in "${pids[@]}"; do kill "$pid" 2>/dev/null || true; done
  rm -rf "$work"
}
trap cleanup EXIT

train_args=(train --config "$config" --total-env-steps "$steps" --set "env.num_actors=$n"
  --set run.log_period=50 --set "run.runs_dir=\"$work/runs\"" --set run.eval_episodes=1)

report() { # label
  local dir
  dir=$(ls -td "$work"/runs/*/ | head -1)
  .venv/bin/python scripts/lib/train_rates.py "$dir" "$1"
  rm -rf "$work/runs"
}

run_timed() { # label command...
  local label=$1 start end
  shift
  start=$(date +%s.%N)
  "$@" >"$work/train.log" 2>&1 || { tail -20 "$work/train.log"; exit 1; }
  end=$(date +%s.%N)
  report "$label"
  printf '    wall of the whole command: %.1f s\n' "$(echo "$end - $start" | bc)" >&2
}

printf '%-40s %10s %14s %18s %14s  %s\n' setup "env steps" "env steps/s" "learner steps/s" "step ms" device

run_timed "one local server (default)" target/release/agent "${train_args[@]}"

: >"$work/servers"
for i in $(seq 1 "$n"); do
  .venv/bin/python -m env_server --port 0 >"$work/server$i.out" 2>"$work/server$i.err" &
  pids+=($!)
done
for i in $(seq 1 "$n"); do
  for _ in $(seq 1 300); do
    grep -q '^LISTENING' "$work/server$i.out" && break
    sleep 0.1
  done
  sed -n 's/^LISTENING //p' "$work/server$i.out" >>"$work/servers"
done
run_timed "$n servers on loopback, file:" target/release/agent "${train_args[@]}" --server "file:$work/servers"
for pid in "${pids[@]}"; do kill "$pid" 2>/dev/null || true; done
pids=()

run_timed "$n servers as Ray actors (local Ray)" .venv/bin/python -m env_server.tools.ray --num-servers "$n" \
  -- target/release/agent "${train_args[@]}"
