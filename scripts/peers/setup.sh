#!/usr/bin/env bash
# The peers' side environment for the MuJoCo benchmark (docs/benchmarks/mujoco.md):
# .venv-peers with Stable-Baselines3 (SAC) and MORL-Baselines (CAPQL) at the exact pins
# of scripts/peers/requirements.lock, never inside .venv. torch and its CUDA wheels are
# hard-linked from .venv when it has them at the pinned versions (link_torch.py), so
# only the rest is downloaded. Safe to re-run: skipped while the lock is unchanged.
set -euo pipefail
cd "$(dirname "$0")/../.."

python=${PYTHON:-python3}
venv=.venv-peers
lock=scripts/peers/requirements.lock
stamp=$venv/.peers-requirements.sha256
want=$(sha256sum "$lock" | cut -d' ' -f1)
[ "$(cat "$stamp" 2>/dev/null)" = "$want" ] && exit 0
if [ ! -x $venv/bin/python ]; then
  echo "==> creating $venv with $($python --version)"
  "$python" -m venv $venv
fi
echo "==> installing the peers' pinned packages into $venv (the first time takes a few minutes)"
$venv/bin/python scripts/peers/link_torch.py .venv $venv "$lock"
$venv/bin/python -m pip install --quiet --disable-pip-version-check pip==25.3
$venv/bin/python -m pip install --quiet --disable-pip-version-check -r "$lock"
echo "$want" > "$stamp"
