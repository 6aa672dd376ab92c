#!/usr/bin/env bash
# Long runs that hold (docs/stability.md): trains a preset for several times its budget on
# N seeds, evaluating the deterministic policy every few thousand env steps, then
# evaluates each run's final policy again on many episodes (`agent eval --episodes E`)
# and prints, per seed and over the seeds: when it solved, its evaluations, its final
# evaluation (the run's own, run.eval_episodes episodes, and the E-episode one with its
# standard error), and whether it holds (bench_mujoco_table.py's criterion).
#
#   scripts/bench_hold.sh [options]
#     --seeds 0,1,..     default 0-9
#     --steps N          env steps per run (default 100000: four times the pendulum preset's)
#     --eval-every N     env steps between evaluations (default 10000)
#     --final-episodes E episodes of the final policy's second evaluation (default 100)
#     --jobs N           runs at once (default 2)
#     --config FILE      default configs/mompo/pendulum.toml
#     --set PATH=VALUE   extra `agent train --set` (repeatable)
#     --out DIR          where the runs and logs go (default bench_out/hold/<start time>)
#
# Why a second evaluation: a pendulum episode's return depends on where it starts (one
# policy's returns spread with a standard deviation near 90), so a run's own few-episode
# evaluation says little about whether its policy is at -150 or -200; E = 100 episodes
# puts the standard error near 9. The first run.eval_episodes of the E episodes are the
# run's own (same seeds and instances). AGENT=path/to/agent runs that binary instead of
# building target/release/agent.
set -euo pipefail
cd "$(dirname "$0")/.."

seeds=0,1,2,3,4,5,6,7,8,9 steps=100000 every=10000 final=100 jobs=2
config=configs/mompo/pendulum.toml out=bench_out/hold/$(date -u +%Y%m%dT%H%M%SZ)
sets=()
while [[ $# -gt 0 ]]; do
  [[ $# -ge 2 ]] || { echo "$1: expected a value after it" >&2; exit 2; }
  case $1 in
    --seeds) seeds=$2 ;; --steps) steps=$2 ;; --eval-every) every=$2 ;;
    --final-episodes) final=$2 ;; --jobs) jobs=$2 ;; --config) config=$2 ;;
    --set) sets+=(--set "$2") ;; --out) out=$2 ;;
    *) echo "unknown option '$1' (see the header of $0)" >&2; exit 2 ;;
  esac
  shift 2
done
for flag in steps:$steps eval-every:$every final-episodes:$final jobs:$jobs; do
  [[ ${flag#*:} =~ ^[1-9][0-9]*$ ]] || { echo "--${flag%%:*}: expected a whole number of at least 1, got '${flag#*:}'" >&2; exit 2; }
done
[[ -f $config ]] || { echo "--config: no config file '$config'" >&2; exit 2; }

scripts/setup.sh
[[ -n ${AGENT:-} ]] || cargo build --locked --release -p agent --bin agent
agent=${AGENT:-target/release/agent}
export MUJOCO_GL=${MUJOCO_GL:-disable}
mkdir -p "$out"
set -m # each run a process group of its own, so that Ctrl-C stops the runs too
pids=()
source scripts/lib/env_server.sh
trap 'for p in "${pids[@]}"; do kill -- -"$p" 2>/dev/null || true; done; stop_env_server; wait' EXIT
start_env_server "$out/server.log"

# One seed: train, then the final policy's E-episode evaluation (eval_final.json in the run).
run() {
  local seed=$1 runs=$out/runs/seed-$1 dir
  "$agent" train --config "$config" --server "$address" --set "seed=$seed" \
    --set "run.total_env_steps=$steps" --set "run.eval_period=$every" \
    --set "run.runs_dir=\"$runs\"" "${sets[@]}" || return 1
  dir=$(ls -d "$runs"/*/ | tail -1) || return 1
  "$agent" eval --checkpoint "$dir" --server "$address" --episodes "$final" --json "$dir/eval_final.json" | tail -1
}
job() {
  local log=$out/seed-$1.log
  echo "==> seed $1: $steps env steps ($log)"
  if run "$1" >"$log" 2>&1; then
    echo "    seed $1:$(tail -1 "$log")"
  else
    echo "FAILED: seed $1 ($log):"; tail -8 "$log"; return 1
  fi
}
failed=0
source scripts/lib/jobs.sh # reap
echo "==> $config ${sets[*]:-}: seeds $seeds, $steps env steps, evaluation every $every, final policy on $final episodes, $jobs at once"
for seed in ${seeds//,/ }; do
  while reap; [[ ${#pids[@]} -ge $jobs ]]; do sleep 2; done
  job "$seed" &
  pids+=($!)
done
while reap; [[ ${#pids[@]} -gt 0 ]]; do sleep 2; done
.venv/bin/python scripts/bench_hold_table.py "$out/runs"
exit $failed
