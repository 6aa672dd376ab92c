//! Multi-objective MPO agents (MO-MPO, MO-V-MPO and their scalarized baselines) that
//! train on environments served by `env_server`.
//!
//! Vocabulary (shared by every module):
//! - **objective**: one named entry of the vector reward (`task`, `action_norm`, ...);
//!   the env declares them in [`core::spec::EnvSpec::objectives`], configs bind to them by name.
//! - **session**: B environment instances on a server, stepped together ([`env::Env`]).
//! - **ε (epsilon)**: the per-objective KL bound that encodes preference (MO-MPO,
//!   MO-V-MPO); scalarized baselines use weights instead.
//!
//! Module map, bottom to top: each group imports only the groups listed before it.
//! - [`core`]: the learner's core, pure (no tokio, tonic or proto): `spec` (what an env
//!   looks like), `learner_config` (the `[learner]` table, paper defaults), `random`
//!   (per-run streams), `device`, `nets`, `algo` (the paper's E- and M-steps), `replay`.
//! - [`env`](mod@env): the env boundary: the `Env` trait, `env::grpc` (the only code that
//!   sees proto types), discovery, the server pool, a local `env_server` process,
//!   `env::error`.
//! - [`report`]: what a run leaves to read: run files (`metrics`), TensorBoard,
//!   figures (`plot`), videos, Pareto measures (`pareto`) and fronts (`front`).
//! - [`runtime`]: one run: its file (`run_config`), the sessions it makes
//!   (`env_setup`), `actor`, `learner`, `schedule` (the rate limiter between them),
//!   `checkpoint`, `resume`, `solve` (time to solve), `eval`, `act`, `train` (a run or
//!   a population), `run_name`.
//! - [`sweep`]: many runs over an ε or weight grid, sharded and merged into fronts.
//!
//! The command line (`main.rs`, `cli/`) sits on top and is the only code that prints.
//!
//! Shape legend used in docs: B batch (env instances, replay samples or unrolls), M
//! sampled actions per state, D action dims, K objectives, P members, T snippet or
//! unroll length.

#![allow(
    clippy::result_large_err,
    reason = "run errors carry paths and sources; they are rare, not on a hot path"
)]

pub mod core;
pub mod env;
pub mod report;
pub mod runtime;
pub mod sweep;
