#!/usr/bin/env bash
# The field's MuJoCo benchmarks, our side and the peers' side by side on this machine
# (docs/benchmarks/mujoco.md): MO-MPO against Stable-Baselines3 SAC on HalfCheetah-v5 and
# Hopper-v5 (100k env steps), ε-conditioned MO-MPO against MORL-Baselines CAPQL on
# mo-halfcheetah-v5 and mo-hopper-2obj-v5 (200k). Every finished run appends its rows to
# the results file; at the end the session's table is printed (scripts/bench_mujoco_table.py
# prints and draws every session's).
#
#   scripts/bench_mujoco.sh [options]
#     --tasks A,B       default HalfCheetah-v5,Hopper-v5,mo-halfcheetah-v5,mo-hopper-2obj-v5
#     --seeds 0,1,2     default 0,1,2
#     --sides ours,peers  default both
#     --steps N         env steps per run (default 100000 single-objective, 200000 two)
#     --eval-every N    env steps between evaluations (default 10000 / 20000; 0: final only)
#     --eval-episodes N  episodes per evaluation on single-objective tasks, both sides
#                       (default 10; two-objective tasks take --capql-eval's E on both)
#     --jobs N          runs at once (default 1)
#     --threads N       torch / libtorch threads per run (default 1)
#     --config TASK=FILE  our run's config for TASK (default configs/mompo/locomotion.toml;
#                       mo-halfcheetah-v5 configs/mompo/locomotion-conditioned.toml,
#                       mo-hopper-2obj-v5 configs/mompo/mo-hopper-conditioned.toml)
#     --set [TASK:]PATH=VALUE  extra `agent train --set` for our runs (of TASK only)
#     --capql-eval W,E  CAPQL's evaluation weights and episodes per weight (default 11,4)
#     --results FILE    default docs/benchmarks/mujoco-results.csv
#     --session ID      default the start time; runs of one session are paired in ratios
#
# Env ids: ours trains `gym:TASK` or `mo:TASK` on one local env_server; the peers make
# TASK with Gymnasium / MO-Gymnasium. Logs and our run folders: bench_out/mujoco/SESSION/.
# AGENT=path/to/agent runs that binary instead of building target/release/agent.
set -euo pipefail
cd "$(dirname "$0")/.."

tasks=HalfCheetah-v5,Hopper-v5,mo-halfcheetah-v5,mo-hopper-2obj-v5
seeds=0,1,2 sides=ours,peers steps="" eval_every="" eval_episodes=10 jobs=1 threads=1 capql_eval=11,4
results=docs/benchmarks/mujoco-results.csv session=$(date -u +%Y%m%dT%H%M%SZ)
declare -A config=()
sets=()
while [[ $# -gt 0 ]]; do
  [[ $# -ge 2 ]] || { echo "$1: expected a value after it" >&2; exit 2; }
  case $1 in
    --tasks) tasks=$2 ;; --seeds) seeds=$2 ;; --sides) sides=$2 ;; --steps) steps=$2 ;;
    --eval-every) eval_every=$2 ;; --eval-episodes) eval_episodes=$2 ;;
    --jobs) jobs=$2 ;; --threads) threads=$2 ;;
    --capql-eval) capql_eval=$2 ;; --results) results=$2 ;; --session) session=$2 ;;
    --config) [[ $2 == *=* ]] || { echo "--config: expected TASK=FILE, got '$2'" >&2; exit 2; }
      config[${2%%=*}]=${2#*=} ;;
    --set) sets+=("$2") ;;
    *) echo "unknown option '$1' (see the header of $0)" >&2; exit 2 ;;
  esac
  shift 2
done
two_objective() { [[ $1 == mo-* ]]; }
for side in ${sides//,/ }; do
  [[ $side == ours || $side == peers ]] || { echo "--sides: expected ours and/or peers, got '$side'" >&2; exit 2; }
done
[[ $eval_episodes =~ ^[1-9][0-9]*$ ]] || { echo "--eval-episodes: expected a positive integer, got '$eval_episodes'" >&2; exit 2; }
for task in ${tasks//,/ }; do
  case $task in
    HalfCheetah-v5 | Hopper-v5 | mo-halfcheetah-v5 | mo-hopper-2obj-v5) ;;
    *) echo "--tasks: expected HalfCheetah-v5, Hopper-v5, mo-halfcheetah-v5 or mo-hopper-2obj-v5, got '$task'" >&2; exit 2 ;;
  esac
  case $task in
    mo-halfcheetah-v5) default=configs/mompo/locomotion-conditioned.toml ;;
    mo-hopper-2obj-v5) default=configs/mompo/mo-hopper-conditioned.toml ;;
    *) default=configs/mompo/locomotion.toml ;;
  esac
  config[$task]=${config[$task]:-$default}
  if [[ $sides == *ours* && ! -f ${config[$task]} ]]; then
    echo "--config: no config file '${config[$task]}' for $task (give one with --config $task=FILE)" >&2; exit 2
  fi
done

out=bench_out/mujoco/$session
mkdir -p "$out"
results=$(realpath -m "$results")
export MUJOCO_GL=${MUJOCO_GL:-disable}
# Each run is a process group of its own (set -m), so that an interrupted benchmark stops
# its runs too (a script's background jobs would otherwise ignore Ctrl-C and go on).
set -m
pids=()
source scripts/lib/env_server.sh
trap 'for p in "${pids[@]}"; do kill -- -"$p" 2>/dev/null || true; done; stop_env_server; wait' EXIT
if [[ $sides == *ours* ]]; then
  scripts/setup.sh
  [[ -n ${AGENT:-} ]] || cargo build --locked --release -p agent --bin agent
  start_env_server "$out/server-$$.log" # one per invocation: two invocations may share a session
fi
[[ $sides == *peers* ]] && scripts/peers/setup.sh
# Every row names the checkout's commit as the session starts (the code its runs use),
# not the commit when the row is written, hours later (scripts/peers/results.py).
BENCH_COMMIT=$(cd scripts && python3 -c 'from peers import results; print(results.commit())')
export BENCH_COMMIT

# One run: its command's output goes to $out/SIDE-TASK-SEED.log. (These run as an `if`
# condition, where set -e does not act: every step checks its own status.)
run_ours() {
  local task=$1 seed=$2 n=$3 every=$4 episodes=$5 family=gym overrides=() s
  two_objective "$task" && family=mo
  for s in "${sets[@]}"; do
    if [[ ${s%%=*} == *:* ]]; then [[ ${s%%:*} == "$task" ]] && overrides+=(--set "${s#*:}"); else overrides+=(--set "$s"); fi
  done
  local runs=$out/runs/$task-$seed
  # The evaluation's settings go into the row's settings, as the peers' rows say theirs.
  overrides=(--set "run.eval_episodes=$episodes" "${overrides[@]}")
  if [[ $every -gt 0 ]]; then overrides=(--set "run.eval_period=$every" "${overrides[@]}"); fi
  "${AGENT:-target/release/agent}" train --config "${config[$task]}" --server "$address" --set "seed=$seed" \
    --set "env.id=\"$family:$task\"" --set "run.total_env_steps=$n" \
    --set "learner.num_threads=$threads" --set "run.runs_dir=\"$runs\"" "${overrides[@]}" || return 1
  local run
  run=$(ls -d "$runs"/*/ | tail -1) || return 1
  .venv/bin/python scripts/bench_mujoco_collect.py "$run" --task "$task" --seed "$seed" \
    --results "$results" --session "$session" --settings "${config[$task]} ${overrides[*]}"
}
run_peers() {
  local task=$1 seed=$2 n=$3 every=$4 episodes=$5 common
  common=(--task "$task" --seed "$seed" --steps "$n" --eval-every "$every" --threads "$threads" --results "$results" --session "$session")
  if two_objective "$task"; then
    .venv-peers/bin/python scripts/peers/capql.py "${common[@]}" --eval-weights "${capql_eval%,*}" --eval-episodes "$episodes"
  else
    .venv-peers/bin/python scripts/peers/sac.py "${common[@]}" --eval-episodes "$episodes"
  fi
}
job() {
  local side=$1 task=$2 seed=$3 n every episodes=$eval_episodes log
  two_objective "$task" && { n=${steps:-200000}; every=${eval_every:-20000}; episodes=${capql_eval#*,}; } \
    || { n=${steps:-100000}; every=${eval_every:-10000}; }
  log=$out/$side-$task-$seed.log
  echo "==> $side $task seed $seed: $n env steps ($log)"
  if "run_$side" "$task" "$seed" "$n" "$every" "$episodes" >"$log" 2>&1; then
    tail -1 "$log"
  else
    echo "FAILED: $side $task seed $seed ($log):"; head -8 "$log"; echo "  ..."; tail -8 "$log"; return 1
  fi
}

# The runs, at most $jobs at once (the server is a job of this shell too, so the runs'
# pids are tracked here); each task's seed runs on both sides before the next seed.
failed=0
source scripts/lib/jobs.sh # reap
echo "==> session $session: tasks $tasks, seeds $seeds, sides $sides, $jobs at once; results $results"
for task in ${tasks//,/ }; do
  for seed in ${seeds//,/ }; do
    for side in ${sides//,/ }; do
      while reap; [[ ${#pids[@]} -ge $jobs ]]; do sleep 2; done
      job "$side" "$task" "$seed" &
      pids+=($!)
    done
  done
done
while reap; [[ ${#pids[@]} -gt 0 ]]; do sleep 2; done
[[ -s $results ]] && .venv/bin/python scripts/bench_mujoco_table.py --results "$results" --session "$session" --plots ""
exit $failed
