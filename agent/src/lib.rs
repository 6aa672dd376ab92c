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
//! Module map, by role (the files still sit side by side; the groups are the ones the
//! pub mod list below is ordered by):
//! - The learner's core, pure (no tokio, tonic or proto): [`spec`] (what an env looks
//!   like), [`config`] (learner configs), [`random`] (the per-run random streams),
//!   [`device`], [`nets`], [`algo`] (the paper's E- and M-steps), [`replay`],
//!   [`checkpoint`].
//! - The env boundary: [`env`](mod@env) (the `Env` trait; `env::grpc` is the only code that sees
//!   proto types; discovery, the server pool, a local `env_server` process for tests and
//!   demos), [`session`] (the sessions a run makes), [`error`].
//! - The runtime of one run: [`run_config`], [`actor`], [`learner`], [`schedule`] (the
//!   rate limiter between them), [`resume`], [`train`], [`eval`], [`solve`], [`act`],
//!   [`run_name`].
//! - Fronts and reports: [`sweep`], [`front`], [`pareto`], [`metrics`], [`tensorboard`],
//!   [`plot`], [`video`].
//!
//! Shape legend used in docs: B batch (env instances, replay samples or unrolls), M
//! sampled actions per state, D action dims, K objectives, T snippet or unroll length.

#![allow(
    clippy::result_large_err,
    reason = "run errors carry paths and sources; they are rare, not on a hot path"
)]

// The learner's core.
pub mod algo;
pub mod checkpoint;
pub mod config;
pub mod device;
pub mod nets;
pub mod random;
pub mod replay;
pub mod spec;

// The env boundary.
pub mod env;
pub mod error;
pub mod session;

// The runtime of one run.
pub mod act;
pub mod actor;
pub mod eval;
pub mod learner;
pub mod resume;
pub mod run_config;
pub mod run_name;
pub mod schedule;
pub mod solve;
pub mod train;

// Fronts and reports.
pub mod front;
pub mod metrics;
pub mod pareto;
pub mod plot;
pub mod sweep;
pub mod tensorboard;
pub mod video;
