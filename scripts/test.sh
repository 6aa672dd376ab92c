#!/usr/bin/env bash
# Set up (scripts/setup.sh), check formatting and lints (cargo fmt, ruff, clippy with
# warnings as errors) and the docs (scripts/docs.sh: the MkDocs site built strictly,
# the paths it names), and run every test: the benchmark scripts' Python
# tests, env_server's Ray tests alone, then the rest of env_server's Python tests beside
# the Rust unit, golden and end-to-end tests (which start real env_server processes on
# 127.0.0.1 with OS-chosen ports).
# Needs no GPU and no network beyond the package registries used by setup.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
# MUJOCO_GL stays as the caller set it: unset, env_server picks a headless OpenGL backend
# (EGL or OSMesa, which setup.sh installs) so the rendering tests really render.

echo "==> format and lints (cargo fmt, ruff, docs)"
cargo fmt --all --check
.venv/bin/ruff format --check .
.venv/bin/ruff check .
scripts/docs.sh

echo "==> the Rust tests' build, with the agent binary (test_ray.py's sweep test runs it), linted by clippy"
# Clippy lints while the test build compiles. `cargo clippy` is `cargo check` with
# clippy-driver (rustc plus clippy's lints) as the workspace members' compiler; made the
# compiler of this build, it lints our crates as it compiles them, and the dependencies
# are compiled once instead of also checked by a separate cold `cargo clippy`. Same
# checks as `cargo clippy --workspace --all-targets -- -D warnings`: every target
# (benches and env_server/native included), warnings as errors (CLIPPY_ARGS is how
# cargo-clippy hands `-D warnings` to the driver; one token, so that it does not depend
# on the driver's separator for several, with which an unknown separator demotes the
# deny to an unknown lint and the lints to warnings). Cargo fingerprints the wrapper, so the
# variables stay exported for `cargo test` below, which then compiles nothing.
# One build for the tests and the agent binary: `cargo build -p agent` would resolve
# features for the agent alone, and the workspace's test build would then compile
# tonic, rustls, tch and the agent a second time with the workspace's features.
clippy_driver="$(rustc --print sysroot)/bin/clippy-driver"
[ -x "$clippy_driver" ] || clippy_driver=$(command -v clippy-driver) || {
  echo "error: no clippy-driver in $(rustc --print sysroot)/bin or on PATH: rustup component add clippy" >&2
  exit 1
}
export RUSTC_WORKSPACE_WRAPPER="$clippy_driver"
export CLIPPY_ARGS="-Dwarnings"
cargo test --locked --workspace --all-targets --no-run

echo "==> the benchmark scripts' Python tests"
.venv/bin/python -m pytest -q scripts/tests

echo "==> env_server's Ray tests, alone (pytest -m serial)"
(cd env_server && ../.venv/bin/python -m pytest -q -m serial tests)

# The rest of env_server's Python suite runs beside the Rust tests. It waits on servers
# and subprocesses more than it computes (the whole suite: 170 CPU-s in 250 s), and most
# Rust test binaries keep one core busy (1,180 CPU-s in 790 s): one after the other they
# left a core idle. Background commands of a script ignore SIGINT, so pytest restores
# Python's handler itself: a Ctrl-C then reaches it and its fixtures stop their servers.
python_log=$(mktemp -t env-server-tests.XXXXXX)
(cd env_server && exec ../.venv/bin/python -c 'import signal, sys, pytest
signal.signal(signal.SIGINT, signal.default_int_handler)
sys.exit(pytest.main(["-q", "-m", "not serial", "tests"]))') >"$python_log" 2>&1 &
python_pid=$!
trap 'kill -INT "$python_pid" 2>/dev/null || true' EXIT
echo "==> env_server's other Python tests, in the background (their output: $python_log)"

echo "==> Rust tests (unit, golden, end-to-end)"
rust_status=0
cargo test --locked --workspace || rust_status=$?

python_status=0
wait "$python_pid" || python_status=$?
trap - EXIT
echo "==> env_server's other Python tests"
cat "$python_log"
if [ "$rust_status" -ne 0 ] || [ "$python_status" -ne 0 ]; then
  echo "error: Rust tests exited $rust_status, env_server's Python tests $python_status" >&2
  exit 1
fi
rm -f "$python_log"
