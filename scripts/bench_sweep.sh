#!/usr/bin/env bash
# What surviving and spreading costs a sweep, end to end: configs/sweeps/dst-quick.toml
# (9 settings, one seed) at a short budget, one run at a time (`parallel = 1`,
# `population = 1`, so walls add up), against one env_server on loopback that every
# command shares:
#   1. the unsharded sweep;
#   2. `--shard 0/2` and `--shard 1/2` one after the other, then `--report` of the two;
#   3. `--resume` of the finished sweep (what a restart of a finished shard costs);
#   4. the sweep killed with SIGKILL halfway through its wall time, then `--resume`d.
# and checks that 2's merged points.csv equals 1's (without the run_dir column).
# On one machine the shards run one after the other: this measures overhead, not speed-up.
#
#   scripts/bench_sweep.sh [ENV_STEPS]      (AGENT=path/to/agent to time another build)
set -euo pipefail
cd "$(dirname "$0")/.."
steps=${1:-5000}
if [ -z "${AGENT:-}" ]; then
  cargo build --locked --release -p agent --bin agent
  AGENT=target/release/agent
fi
work=$(mktemp -d)
server=""
cleanup() {
  [ -n "$server" ] && kill "$server" 2>/dev/null || true
  rm -rf "$work"
}
trap cleanup EXIT

sed 's|^base = "../mompo/dst.toml"|base = "'"$PWD"'/configs/mompo/dst.toml"|; s|^parallel = [0-9]*|parallel = 1\npopulation = 1|' \
  configs/sweeps/dst-quick.toml >"$work/sweep.toml"
.venv/bin/python -m env_server --port 0 >"$work/server.out" 2>"$work/server.err" &
server=$!
for _ in $(seq 1 300); do
  grep -q '^LISTENING' "$work/server.out" && break
  sleep 0.1
done
address=$(awk '/^LISTENING/ {print $2}' "$work/server.out")
export RUST_LOG=warn

now() { date +%s.%N; }
timed() { # label command...
  local label=$1 start end
  shift
  start=$(now)
  "$@" >"$work/last.log" 2>&1 || { tail -20 "$work/last.log"; exit 1; }
  end=$(now)
  printf '%-44s %7.1f s\n' "$label" "$(echo "$end - $start" | bc)"
}
# A checkpoint every 200 learner steps (the preset's 2000 is past a short run's end), so
# that the killed sweep's run in progress continues from one instead of starting over.
sweep=("$AGENT" sweep --config "$work/sweep.toml" --total-env-steps "$steps" --server "$address"
  --set run.checkpoint_period=200)

start=$(now)
timed "unsharded sweep" "${sweep[@]}" --dir "$work/whole"
whole=$(echo "$(now) - $start" | bc)
timed "shard 0/2" "${sweep[@]}" --shard 0/2 --dir "$work/s0"
timed "shard 1/2" "${sweep[@]}" --shard 1/2 --dir "$work/s1"
timed "report of the 2 shards" "$AGENT" sweep --report "$work/s0" "$work/s1" --dir "$work/merged"
timed "resume of the finished sweep" "$AGENT" sweep --resume "$work/whole" --server "$address"
if diff <(cut -d, -f1-8 "$work/whole/points.csv") <(cut -d, -f1-8 "$work/merged/points.csv") >/dev/null; then
  echo "merged points.csv equals the unsharded sweep's (run_dir aside)"
else
  echo "merged points.csv DIFFERS from the unsharded sweep's"
fi

half=$(echo "$whole / 2" | bc -l)
start=$(now)
"${sweep[@]}" --dir "$work/killed" >"$work/killed.log" 2>&1 &
pid=$!
sleep "$half"
kill -9 "$pid"
wait "$pid" 2>/dev/null || true
killed_at=$(echo "$(now) - $start" | bc)
done_jobs=$(ls "$work"/killed/runs/*/*/summary.json 2>/dev/null | wc -l)
timed "resume after a SIGKILL at ${killed_at%.*} s ($done_jobs of 6 done)" "$AGENT" sweep --resume "$work/killed" --server "$address"
printf '%-44s %7.1f s\n' "killed + resumed, in all" "$(echo "$(now) - $start" | bc)"
