#!/usr/bin/env bash
# Set up (scripts/setup.sh), check formatting and lints (cargo fmt, clippy with
# warnings as errors, ruff) and the docs (scripts/docs.sh: the MkDocs site built
# strictly, the paths it names), and run every test: env_server's and the benchmark
# scripts' Python tests, then the Rust unit, golden and end-to-end tests (which start
# real env_server processes on 127.0.0.1 with OS-chosen ports). Needs no GPU and no
# network beyond the package registries used by setup.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
# MUJOCO_GL stays as the caller set it: unset, env_server picks a headless OpenGL backend
# (EGL or OSMesa, which setup.sh installs) so the rendering tests really render.

echo "==> format and lints (cargo fmt, ruff, docs, clippy)"
cargo fmt --all --check
.venv/bin/ruff format --check .
.venv/bin/ruff check .
scripts/docs.sh
cargo clippy --locked --workspace --all-targets -- -D warnings

echo "==> the Rust tests' build, with the agent binary (test_ray.py's sweep test runs it)"
# One build for both: `cargo build -p agent` would resolve features for the agent
# alone, and the workspace's test build would then compile tonic, rustls, tch and the
# agent a second time with the workspace's features.
cargo test --locked --workspace --no-run

echo "==> Python tests (env_server, then the benchmark scripts)"
(cd env_server && ../.venv/bin/python -m pytest -q tests)
.venv/bin/python -m pytest -q scripts/tests

echo "==> Rust tests (unit, golden, end-to-end)"
cargo test --locked --workspace
