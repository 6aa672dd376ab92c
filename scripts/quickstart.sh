#!/usr/bin/env bash
# Set up everything (scripts/setup.sh) and run the main job on its defaults:
# start a local env_server, connect the Rust agent, and step `dst` and
# `humanoid-run` with random actions, printing each episode's vector return.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
cargo build --locked --release -p agent --bin agent
export MUJOCO_GL=${MUJOCO_GL:-disable}
target/release/agent envs
target/release/agent demo "$@"
