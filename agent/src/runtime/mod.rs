//! The runtime of one run: its config, the env sessions it makes, actors, the learner
//! loop, the rate limiter between them, checkpoints and resume, time to solve,
//! deterministic evaluation, and `train`, which opens, starts, waits for and finishes a
//! run or a population around them. Sweeps build on it; it never imports them.

pub mod act;
pub mod actor;
pub mod checkpoint;
pub mod env_setup;
pub mod eval;
pub mod learner;
pub mod resume;
pub mod run_config;
pub mod run_name;
pub mod schedule;
pub mod solve;
pub mod train;
