#!/usr/bin/env bash
# Runs end-to-end test binaries N times and reports every failure: a flake shows as a
# FAIL line with its log. Usage:
#   scripts/stress.sh N [TEST ...]
# TEST is the name of a test binary of any workspace crate (tests/tests/NAME.rs,
# agent/tests/NAME.rs); PACKAGE:NAME (agent:ray) is accepted too and only labels the
# report. Default: every integration-tests binary.
# Each binary runs its tests side by side, as `cargo test` does. Logs go to
# stress-logs/<time>/<test>-<i>.log. Run it beside a training run to test under load.
set -euo pipefail
cd "$(dirname "$0")/.."
n=${1:?usage: scripts/stress.sh N [TEST ...]}
shift
tests=("$@")
if [ ${#tests[@]} -eq 0 ]; then
  for f in tests/tests/*.rs; do tests+=("$(basename "$f" .rs)"); done
fi
# --workspace, not -p PACKAGE, for the reason learning_seeds.sh gives.
cargo test --locked -q --workspace --tests --no-run
logs=stress-logs/$(date +%Y%m%d-%H%M%S)
mkdir -p "$logs"
failures=0
for i in $(seq 1 "$n"); do
  for t in "${tests[@]}"; do
    package=integration-tests name=$t
    if [[ $t == *:* ]]; then package=${t%%:*} name=${t#*:}; fi
    log="$logs/$name-$i.log"
    started=$(date +%s)
    if cargo test --locked -q --workspace --test "$name" >"$log" 2>&1; then
      echo "round $i/$n  $package:$name  pass  $(($(date +%s) - started)) s"
    else
      failures=$((failures + 1))
      echo "round $i/$n  $package:$name  FAIL  $(($(date +%s) - started)) s  (see $log)"
    fi
  done
done
echo "$failures failure(s) in $n round(s) of ${#tests[@]} binaries; logs in $logs"
[ "$failures" -eq 0 ]
