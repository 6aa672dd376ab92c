#!/bin/sh
# The agent-sweep indexed Job's command: run shard $JOB_COMPLETION_INDEX of $SHARDS of the
# sweep $SWEEP_CONFIG, or resume it.
#
#   sweep-shard.sh [agent sweep flags...]      (e.g. --server ... --tls-ca ... --token-file ...)
#
# Kubernetes sets JOB_COMPLETION_INDEX (0 .. completions - 1) in each pod of an Indexed Job.
# The shard's folder is $SWEEP_ROOT/shard-<I>-of-<N>/ (on the agent-sweeps volume):
#   - no sweep.json there (a first pod, or one that died before writing it):
#     `agent sweep --config $SWEEP_CONFIG --shard I/N --dir FOLDER`;
#   - otherwise `agent sweep --resume FOLDER`, which keeps the shard's finished runs,
#     continues the others from their checkpoints and writes the shard's front again
#     (a finished shard costs a second).
# The flags given to this script go to `agent sweep` in both cases; LEARNER_DEVICE, when
# set, becomes --device. `exec` hands the agent this process, so it receives the pod's
# SIGTERM and its runs write their final checkpoints.
set -eu

index=${JOB_COMPLETION_INDEX:?"expected JOB_COMPLETION_INDEX (an Indexed Job sets it), got none"}
shards=${SHARDS:?"expected SHARDS (the Job's completions), got none"}
root=${SWEEP_ROOT:-/sweeps/sweep}
config=${SWEEP_CONFIG:-/etc/agent/sweep/sweep.toml}
agent=${AGENT:-agent}
dir="$root/shard-$index-of-$shards"

if [ -n "${LEARNER_DEVICE:-}" ]; then
  set -- "$@" --device "$LEARNER_DEVICE"
fi

if [ -f "$dir/sweep.json" ]; then
  echo "sweep-shard: resuming $dir" >&2
  exec "$agent" sweep --resume "$dir" "$@"
fi
echo "sweep-shard: starting shard $index/$shards of $config in $dir" >&2
exec "$agent" sweep --config "$config" --shard "$index/$shards" --dir "$dir" "$@"
