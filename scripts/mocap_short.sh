#!/usr/bin/env bash
# A short humanoid-mocap comparison of MO-V-MPO (equal epsilon) and scalarized V-MPO
# (eq. 8, lambda = 1) on the shipped SYNTHETIC clips, sized for a CPU: the shipped
# configs (Table 5) with a batch of BATCH unrolls instead of 128 and STEPS env steps.
# Writes runs under runs/mocap-short/ and copies each run's curves.png to docs/results/.
set -euo pipefail
cd "$(dirname "$0")/.."
STEPS="${STEPS:-60000}"
BATCH="${BATCH:-16}"
OUT=runs/mocap-short
mkdir -p "$OUT" docs/results
cargo build --release -p agent --bin agent
for algo in movmpo vmpo; do
  sed -e "s/^batch_size = 128/batch_size = $BATCH/" \
      -e "s|^\[run\]|[run]\nruns_dir = \"$OUT\"|" \
      "configs/$algo/humanoid-mocap.toml" > "$OUT/$algo.toml"
  MUJOCO_GL=disable target/release/agent train --config "$OUT/$algo.toml" --total-env-steps "$STEPS"
  run=$(ls -td "$OUT"/humanoid-mocap__"$algo"__* | head -1)
  cp "$run/curves.png" "docs/results/mocap-$algo.png"
done
