//! The learner's core: what an env looks like, the learner's config, the per-run random
//! streams, the device, the networks, the paper's E- and M-steps and replay. Pure: no
//! tokio, tonic or proto, and nothing here imports the env boundary, the reports or the
//! runtime above it.
//!
//! Shape legend: B batch, M sampled actions, D action dims, K objectives, P members,
//! T snippet or unroll length.

pub mod algo;
pub mod device;
pub mod learner_config;
pub mod nets;
pub mod random;
pub mod replay;
pub mod spec;
