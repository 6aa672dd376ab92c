#!/bin/sh
# The agent-train Job's command: train the run of $TRAIN_CONFIG, or resume it.
#
#   train-or-resume.sh [agent train flags...]      (e.g. --server ... --tls-ca ... --token-file ...)
#
# Each Job keeps its run under $RUNS_ROOT/$JOB_NAME/ (on the agent-runs volume). The agent
# names the run directory itself (<task>__<algo>__<seed>__<time>), so this script looks
# there for a run with a checkpoint (checkpoints/latest.json):
#   - none: `agent train --config $TRAIN_CONFIG` with run.runs_dir set to that directory
#     (a directory an earlier pod left without a checkpoint is not resumed);
#   - one that finished (summary.json with "interrupted": null): nothing to do, exit 0;
#   - otherwise the newest: `agent train --resume DIR`, which continues from its latest
#     checkpoint with the same step counters, duals and optimizer state (the replay
#     buffer is refilled).
# The flags given to this script go to `agent train` in both cases; LEARNER_DEVICE, when
# set, becomes --device. `exec` hands the agent this process, so it receives the pod's
# SIGTERM and writes its final checkpoint.
set -eu

runs_root=${RUNS_ROOT:-/runs}
job=${JOB_NAME:-agent-train}
config=${TRAIN_CONFIG:-/etc/agent/config/train.toml}
agent=${AGENT:-agent}
runs="$runs_root/$job"
mkdir -p "$runs"

if [ -n "${LEARNER_DEVICE:-}" ]; then
  set -- "$@" --device "$LEARNER_DEVICE"
fi

# Run directories end in the UTC start time, YYYYMMDD-HHMMSS (with -2, -3, ... for a
# second run in the same second), so within one Job (one config: one task, algo and
# seed) name order is start order.
latest=""
for dir in "$runs"/*/; do
  if [ -f "${dir}checkpoints/latest.json" ]; then
    latest=${dir%/}
  fi
done

if [ -z "$latest" ]; then
  echo "train-or-resume: no checkpoint under $runs: starting $config" >&2
  exec "$agent" train --config "$config" --set "run.runs_dir=\"$runs\"" "$@"
fi
if [ -f "$latest/summary.json" ] && grep -q '"interrupted": null' "$latest/summary.json"; then
  echo "train-or-resume: $latest finished (summary.json): nothing to do" >&2
  exit 0
fi
echo "train-or-resume: resuming $latest" >&2
exec "$agent" train --resume "$latest" "$@"
