#!/usr/bin/env bash
# A short humanoid-mocap comparison of MO-V-MPO (equal epsilon) and scalarized V-MPO
# (eq. 8, lambda = 1) on the shipped SYNTHETIC clips, sized for a CPU: the shipped
# configs (Table 5) with a batch of BATCH unrolls instead of 128 and STEPS env steps.
# Writes runs under runs/mocap-short/ and copies each run's curves.png to docs/results/.
#
# SETTINGS=table5 (default) keeps the rest of Table 5. SETTINGS=reuse applies what the
# pendulum presets taught (docs/vmpo-pendulum.md): each batch used for EPOCHS passes over
# 2 minibatches with pi_old renewed every learner step, beta_Sigma 1e-3 and a dual
# learning rate of 0.1; its figures are written as mocap-reuse-<algo>.png.
set -euo pipefail
cd "$(dirname "$0")/.."
STEPS="${STEPS:-60000}"
BATCH="${BATCH:-16}"
SETTINGS="${SETTINGS:-table5}"
EPOCHS="${EPOCHS:-4}"
OUT=runs/mocap-short
case "$SETTINGS" in
  table5) extra=(); prefix=mocap ;;
  reuse)
    extra=(--set learner.vmpo.epochs="$EPOCHS" --set learner.vmpo.minibatches=2
           --set learner.vmpo.target_update_period=1 --set learner.vmpo.beta_cov=1e-3
           --set learner.vmpo.dual_learning_rate=0.1)
    prefix=mocap-reuse ;;
  *) echo "SETTINGS must be table5 or reuse, got '$SETTINGS'" >&2; exit 2 ;;
esac
mkdir -p "$OUT" docs/results
cargo build --release -p agent --bin agent
for algo in movmpo vmpo; do
  sed -e "s/^batch_size = 128/batch_size = $BATCH/" \
      -e "s|^\[run\]|[run]\nruns_dir = \"$OUT\"|" \
      "configs/$algo/humanoid-mocap.toml" > "$OUT/$algo.toml"
  MUJOCO_GL=disable target/release/agent train --config "$OUT/$algo.toml" \
    --total-env-steps "$STEPS" "${extra[@]}"
  run=$(ls -td "$OUT"/humanoid-mocap__"$algo"__* | head -1)
  cp "$run/curves.png" "docs/results/$prefix-$algo.png"
done
