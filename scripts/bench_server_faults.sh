#!/usr/bin/env bash
# The env server's latency for a well-behaved client while another misbehaves (a
# connection reset mid-stream, a half-open connection, a message trickled byte by
# byte, sessions abandoned), on both fronts: the bystander's median step before and
# during each fault, and their ratio, from tests/tests/server_faults.rs (which also
# checks that the bystander never fails and that the server frees what the other
# client held). Run on a quiet machine for figures worth comparing.
set -euo pipefail
cd "$(dirname "$0")/.."
cargo test --locked -q -p integration-tests --test server_faults -- --nocapture --test-threads 1 2>&1 \
  | grep -E "front, |front: RSS"
