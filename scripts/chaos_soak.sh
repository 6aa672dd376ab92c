#!/usr/bin/env bash
# The chaos soak (issue 36): DST runs back to back through a fault-injection proxy to a
# real env_server for SECONDS (default 600), an off-policy run, an on-policy run and a
# population in turn, with a random fault (delay, throttle, trickle, drop, reset,
# blackhole, slow close) of 0.5-3 s every 3-7 s. Every run must reach its budget with
# exact counters, every log row once and no session left on the server; the figures
# for docs/reliability.md are printed at the end. Not part of scripts/test.sh.
# Usage: scripts/chaos_soak.sh [SECONDS] [SEED]
set -euo pipefail
cd "$(dirname "$0")/.."
CHAOS_SOAK_SECONDS=${1:-600} CHAOS_SEED=${2:-1} \
  cargo test --locked -q -p integration-tests --test faults -- --ignored chaos_soak --nocapture
