#!/bin/sh
# The agent-sweep-report Job's command: wait until every shard folder of the sweep under
# $SWEEP_ROOT has its front (a shard writes summary.json when all its runs have finished),
# then merge them: `agent sweep --report shard-0-of-N ... --dir $SWEEP_ROOT/front`.
#
# Kubernetes has no "after that Job" for Jobs, so this one waits for the files instead
# (every $POLL_S seconds, 60 by default). The merge reads only the volume: no server.
set -eu

shards=${SHARDS:?"expected SHARDS (the sweep Job's completions), got none"}
root=${SWEEP_ROOT:-/sweeps/sweep}
agent=${AGENT:-agent}
poll=${POLL_S:-60}

set --
i=0
while [ "$i" -lt "$shards" ]; do
  set -- "$@" "$root/shard-$i-of-$shards"
  i=$((i + 1))
done

for dir in "$@"; do
  until [ -f "$dir/summary.json" ]; do
    echo "sweep-report: waiting for $dir/summary.json" >&2
    sleep "$poll"
  done
done
echo "sweep-report: merging $# shards into $root/front" >&2
exec "$agent" sweep --report "$@" --dir "$root/front"
