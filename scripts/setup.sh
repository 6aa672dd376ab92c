#!/usr/bin/env bash
# Set up the Python side on a fresh machine: the venv (.venv) with the pinned
# simulators, grpc and torch (whose libtorch the Rust agent links), and
# env_server installed into it. Safe to re-run: skipped when already up to date.
# scripts/quickstart.sh and scripts/test.sh call this, then build with cargo.
set -euo pipefail
cd "$(dirname "$0")/.."

python=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  echo "==> creating .venv with $($python --version)"
  "$python" -m venv .venv
fi

# Reinstall only when the pins changed (pip's own check takes ~10 s on this venv).
stamp=.venv/.mo-mpo-requirements.sha256
want=$(cat requirements.lock env_server/pyproject.toml | sha256sum | cut -d' ' -f1)
if [ "$(cat "$stamp" 2>/dev/null)" != "$want" ]; then
  echo "==> installing pinned Python packages (torch is large; the first time takes a few minutes)"
  .venv/bin/python -m pip install --quiet --disable-pip-version-check pip==25.3
  .venv/bin/python -m pip install --quiet --disable-pip-version-check -r requirements.lock
  .venv/bin/python -m pip install --quiet --disable-pip-version-check --no-deps --no-build-isolation -e env_server
  echo "$want" > "$stamp"
fi

# The Rust side needs nothing else: .cargo/config.toml points libtorch's build at
# .venv, and cargo fetches the crates on first build (done by the callers).
