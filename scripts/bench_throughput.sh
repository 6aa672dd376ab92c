#!/usr/bin/env bash
# End-to-end throughput of `agent train` on this machine: env steps/s and learner
# steps/s once the replay is warm, for dst, pendulum and humanoid-run, each with its
# shipped preset and one local env_server. The rates are taken between the first and
# the last learner.jsonl record of a short run (so the replay warm-up is excluded).
#
#   scripts/bench_throughput.sh [--set PATH=VALUE ...]   # extra settings for every run
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
cargo build --locked --release -p agent --bin agent
export MUJOCO_GL=${MUJOCO_GL:-disable}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
# config | env steps | learner.jsonl period (learner steps)
runs=(
  "configs/mompo/dst.toml|12000|50"
  "configs/mompo/pendulum.toml|12000|50"
  "configs/mompo/humanoid-run.toml|10400|5"
)
printf '%-40s %10s %14s %18s %14s  %s\n' config "env steps" "env steps/s" "learner steps/s" "step ms" device
for run in "${runs[@]}"; do
  IFS='|' read -r config steps period <<<"$run"
  target/release/agent train --config "$config" --total-env-steps "$steps" --set "run.log_period=$period" \
    --set "run.runs_dir=\"$work/runs\"" --set run.eval_episodes=1 "$@" >"$work/train.log" 2>&1 \
    || { tail -20 "$work/train.log"; exit 1; }
  dir=$(ls -td "$work"/runs/*/ | head -1)
  .venv/bin/python scripts/lib/train_rates.py "$dir" "$config"
  rm -rf "$work/runs"
done
