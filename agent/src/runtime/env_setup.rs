//! The env sessions a run makes: their options from the run config (id, kwargs, seed),
//! and the env's spec, probed from a one-instance session.

use crate::core::spec::EnvSpec;
use crate::env::error::EnvError;
use crate::env::grpc::EnvClient;
use crate::env::{Env, MakeOptions};
use crate::runtime::run_config::TrainConfig;

/// A session of `num_envs` instances of the run's env, instance i seeded `seed + i`.
pub fn make_options(cfg: &TrainConfig, num_envs: usize, seed: u64) -> MakeOptions {
    MakeOptions {
        kwargs: cfg.env.kwargs.clone(),
        seed: Some(seed),
        ..MakeOptions::new(&cfg.env.id, num_envs)
    }
}

/// The env's spec, from a one-instance session made and closed at once.
pub async fn probe_spec(client: &EnvClient, cfg: &TrainConfig) -> Result<EnvSpec, EnvError> {
    let env = client.make(&make_options(cfg, 1, cfg.seed)).await?;
    let spec = env.spec().clone();
    env.close().await?;
    Ok(spec)
}
