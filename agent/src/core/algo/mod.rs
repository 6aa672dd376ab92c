//! MO-MPO and scalarized MPO (Abdolmaleki et al. 2020, appendix C, Algorithm 3):
//! policy evaluation with Retrace, per-objective E-steps, one decoupled M-step; and
//! MO-V-MPO and scalarized V-MPO (appendix D): T-step value targets, top-k advantage
//! weights, the same decoupled policy fit. One `Learner` (`state.rs`)
//! runs all four. Pure library code: no tokio, tonic or proto types.
//!
//! Shape legend: B batch, M sampled actions, D action dims, K objectives,
//! C learned critics, T snippet length.

pub mod adam;
pub mod batch;
pub mod dual;
pub mod estep;
pub mod members;
pub mod mompo;
pub mod movmpo;
mod mpo_eval;
pub mod mstep;
mod networks;
pub mod noise;
pub mod objectives;
pub mod population;
pub mod preferences;
pub mod projection;
pub mod real_states;
pub mod retrace;
pub mod state;
pub mod stats;
pub mod update;
pub mod vmpo_estep;
mod vmpo_trust;

pub use batch::{BatchError, SnippetBatch};
pub use noise::{NoiseError, NoiseSource};
pub use objectives::{BoundObjectives, LearnerDims, QSource, bind};
pub use state::{Learner, LearnerError, LearnerStats, PhaseTimings};
