//! Multi-objective MPO agents (MO-MPO, MO-V-MPO and their scalarized baselines) that
//! train on environments served by `env_server`.
//!
//! Vocabulary (shared by every module):
//! - **objective**: one named entry of the vector reward (`task`, `action_norm`, ...);
//!   the env declares them in [`spec::EnvSpec::objectives`], configs bind to them by name.
//! - **session**: B environment instances on a server, stepped together ([`env::Env`]).
//! - **ε (epsilon)**: the per-objective KL bound that encodes preference (MO-MPO,
//!   MO-V-MPO); scalarized baselines use weights instead.
//!
//! Module map:
//! - [`spec`]: plain-Rust env spec (spaces, objectives).
//! - [`env`]: the `Env` trait, the gRPC client (`env::grpc`, the only code that sees proto types),
//!   and a helper that starts a local `env_server` process (tests and demos use a real one).
//! - `config`, `nets`, `algo`, `checkpoint`: the learner (pure; no tokio, tonic or proto).
//! - [`random`]: the per-run random streams every draw comes from (keyed by seed and
//!   purpose), and the one locked use of libtorch's global generator (initialisation).
//!
//! Shape legend used in docs: B batch (env instances, replay samples or unrolls), M
//! sampled actions per state, D action dims, K objectives, T snippet or unroll length.

#![allow(
    clippy::result_large_err,
    reason = "run errors carry paths and sources; they are rare, not on a hot path"
)]

pub mod act;
pub mod actor;
pub mod algo;
pub mod checkpoint;
pub mod config;
pub mod device;
pub mod env;
pub mod error;
pub mod eval;
pub mod front;
pub mod learner;
pub mod metrics;
pub mod nets;
pub mod pareto;
pub mod plot;
pub mod random;
pub mod replay;
pub mod resume;
pub mod run_config;
pub mod run_name;
pub mod schedule;
pub mod session;
pub mod solve;
pub mod spec;
pub mod sweep;
pub mod tensorboard;
pub mod train;
pub mod video;
