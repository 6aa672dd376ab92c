//! `train --video-every N`: while a run trains, a video of one deterministic episode of
//! the newest published policy every N env steps, under `<run>/videos/`.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use tch::Device;
use tokio::sync::watch;

use crate::core::algo::objectives::LearnerDims;
use crate::core::nets::{ActorPolicy, PolicySnapshot};
use crate::env::grpc::EnvClient;
use crate::report::video::VideoOptions;
use crate::runtime::eval::evaluate_recorded;
use crate::runtime::run_config::TrainConfig;
use crate::runtime::schedule::Schedule;

/// The parts of a running training job the recorder reads.
#[derive(Debug)]
pub(super) struct PeriodicContext {
    /// Where evaluation sessions are made.
    pub client: EnvClient,
    /// The run's config (env, network).
    pub cfg: TrainConfig,
    /// Network sizes.
    pub dims: LearnerDims,
    /// ε-conditioned runs: the preference features the videos are taken at.
    pub preference: Option<Vec<f32>>,
    /// The learner's published parameters.
    pub params: watch::Receiver<Arc<PolicySnapshot>>,
    /// Env-step counter and stop flag.
    pub schedule: Arc<Schedule>,
    /// `<run>/videos`.
    pub dir: PathBuf,
}

/// Record a video each time the env-step count passes the next multiple of `every`,
/// until the run stops. A failed video is logged and ends the periodic videos; it
/// never stops training.
pub(super) async fn record_periodically(ctx: PeriodicContext, every: u64, options: VideoOptions) {
    let every = every.max(1);
    let mut next = (ctx.schedule.counters().env_steps / every + 1) * every;
    loop {
        tokio::time::sleep(Duration::from_millis(500)).await;
        let counters = ctx.schedule.counters();
        if counters.stop {
            return;
        }
        if counters.env_steps < next {
            continue;
        }
        let mut policy = ActorPolicy::new(&ctx.cfg.learner.network, &ctx.dims, Device::Cpu);
        let snapshot = ctx.params.borrow().clone();
        if let Err(e) = policy.load(&snapshot) {
            tracing::warn!(error = %e, "periodic video: cannot load the policy; no more videos");
            return;
        }
        if let Some(features) = &ctx.preference {
            policy = policy.at_preference(features);
        }
        let path = ctx
            .dir
            .join(format!("env_steps_{:09}.mp4", counters.env_steps));
        match evaluate_recorded(&ctx.client, &ctx.cfg, policy, 1, &path, &options).await {
            Ok((episodes, video)) => tracing::info!(
                path = %video.path.display(),
                frames = video.frames,
                env_steps = counters.env_steps,
                episode_return = ?episodes.first().map(|e| &e.episode_return),
                "wrote a video"
            ),
            Err(e) => {
                tracing::warn!(error = %e, "periodic video failed; no more videos this run");
                return;
            }
        }
        next = (counters.env_steps / every + 1) * every;
    }
}
