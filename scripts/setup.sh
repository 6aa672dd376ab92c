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
  # torch with its CUDA libraries makes .venv about 7 GiB and pip unpacks beside it;
  # say so before pip stops halfway with "No space left on device".
  need_gib=8
  free_gib=$(( $(df -Pk . | awk 'NR == 2 {print $4}') / 1024 / 1024 ))
  if [ "$free_gib" -lt "$need_gib" ]; then
    echo "error: installing .venv needs about $need_gib GiB free on $(df -P . | awk 'NR == 2 {print $6}') (torch and its CUDA libraries), found $free_gib GiB; the Rust build needs about 5 GiB more for target/" >&2
    exit 1
  fi
  echo "==> installing pinned Python packages (torch is large; the first time takes a few minutes)"
  .venv/bin/python -m pip install --quiet --disable-pip-version-check pip==25.3
  .venv/bin/python -m pip install --quiet --disable-pip-version-check -r requirements.lock
  .venv/bin/python -m pip install --quiet --disable-pip-version-check --no-deps --no-build-isolation -e env_server
  echo "$want" > "$stamp"
fi

# env_server's native gRPC front (the Rust extension in env_server/native; the server
# falls back to grpc.aio without it), rebuilt when its sources or pins change.
native_stamp=.venv/.mo-mpo-native.sha256
native_want=$(cat env_server/native/Cargo.toml env_server/native/pyproject.toml env_server/native/src/*.rs \
  Cargo.toml Cargo.lock proto/mo_env/v1/env.proto | sha256sum | cut -d' ' -f1)
if [ "$(cat "$native_stamp" 2>/dev/null)" != "$native_want" ] || ! .venv/bin/python -c "import env_server_native" 2>/dev/null; then
  echo "==> building env_server's native gRPC front (env_server/native, Rust; the first time takes a minute)"
  (cd env_server/native && VIRTUAL_ENV="$(cd ../.. && pwd)/.venv" ../../.venv/bin/maturin develop --release --locked)
  echo "$native_want" > "$native_stamp"
fi

# Offscreen MuJoCo rendering (the Render RPC, videos) needs a headless OpenGL: EGL or
# OSMesa, here Mesa's software renderers (env_server/gl.py picks one when serving).
if [ "$(.venv/bin/python -c 'from env_server import gl; print(gl.detect())')" = disable ]; then
  gl_packages="libegl1 libegl-mesa0 libosmesa6"
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    echo "==> installing Mesa's software OpenGL for offscreen rendering: apt-get install $gl_packages"
    apt-get install -y -qq $gl_packages >/dev/null || { apt-get update -qq && apt-get install -y -qq $gl_packages >/dev/null; }
  else
    echo "==> no headless OpenGL found: MuJoCo frames (Render, videos) need: sudo apt-get install $gl_packages"
  fi
fi

# The Rust side needs nothing else: .cargo/config.toml points libtorch's build at
# .venv, and cargo fetches the crates on first build (done by the callers).
