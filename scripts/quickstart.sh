#!/usr/bin/env bash
# Set up everything (scripts/setup.sh) and run the main job on its defaults: start a
# local env_server, train MO-MPO on Deep Sea Treasure for nine epsilon_treasure /
# epsilon_time ratios (configs/sweeps/dst-quick.toml, a few minutes on 2 cores),
# and print which treasure each policy reaches, the front's hypervolume, and where
# the plots are. An optional argument names another sweep file.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
cargo build --locked --release -p agent --bin agent
export MUJOCO_GL=${MUJOCO_GL:-disable}
exec target/release/agent sweep --config "${1:-configs/sweeps/dst-quick.toml}"
