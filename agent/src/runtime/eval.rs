//! Evaluation of a deterministic policy through the server (the end of `train` and of
//! every sweep run, and `agent eval` on a checkpoint): the server reports each episode's
//! undiscounted and discounted vector returns, so every client is evaluated alike.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::Serialize;
use tch::{Device, Tensor};

use crate::core::algo::Learner;
use crate::core::algo::preferences::PreferenceGrid;
use crate::core::learner_config::ConfigError;
use crate::core::nets::{Acting, ActorPolicy, LearnerDims};
use crate::env::connection::ConnectionConfig;
use crate::env::error::EnvError;
use crate::env::grpc::{EnvClient, RemoteEnv};
use crate::env::pool::ServerPool;
use crate::env::{Env, EpisodeSummary, StepResult};
use crate::report::metrics::mean_of;
use crate::report::video::{Recorder, VideoOptions, VideoReport};
use crate::runtime::actor::ActionMap;
use crate::runtime::checkpoint::run::latest_checkpoint;
use crate::runtime::env_setup::{make_options, probe_spec};
use crate::runtime::run_config::TrainConfig;

/// Errors of evaluating a policy or a checkpoint.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    /// A bad argument or config (`--checkpoint`, `--epsilon`, the run's config.toml).
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// Talking to the env server failed.
    #[error(transparent)]
    Env(#[from] EnvError),
    /// The checkpoint could not be found or read.
    #[error(transparent)]
    Checkpoint(#[from] crate::runtime::checkpoint::CheckpointError),
    /// Recording the evaluation's video failed.
    #[error(transparent)]
    Video(#[from] crate::report::video::VideoError),
    /// The checkpoint's parameters do not fit its policy.
    #[error("policy snapshot: {0}")]
    Snapshot(String),
}

/// Watches an evaluation session after its reset and after every step (a video
/// [`Recorder`] renders it); its errors include the session's own.
#[allow(
    async_fn_in_trait,
    reason = "used with concrete types inside this crate's runtime"
)]
pub trait EvalObserver {
    /// What observing can fail with.
    type Error: From<EnvError>;
    /// The session was just reset (all instances).
    async fn on_reset(&mut self, env: &RemoteEnv) -> Result<(), Self::Error>;
    /// The session just took `step`.
    async fn on_step(&mut self, env: &RemoteEnv, step: &StepResult) -> Result<(), Self::Error>;
}

/// Observes nothing.
struct Unobserved;

impl EvalObserver for Unobserved {
    type Error = EnvError;

    async fn on_reset(&mut self, _: &RemoteEnv) -> Result<(), EnvError> {
        Ok(())
    }

    async fn on_step(&mut self, _: &RemoteEnv, _: &StepResult) -> Result<(), EnvError> {
        Ok(())
    }
}

impl EvalObserver for Recorder {
    type Error = crate::report::video::VideoError;

    async fn on_reset(&mut self, env: &RemoteEnv) -> Result<(), Self::Error> {
        self.record_reset(env).await
    }

    async fn on_step(&mut self, env: &RemoteEnv, step: &StepResult) -> Result<(), Self::Error> {
        self.record_step(env, step).await
    }
}

/// Run the deterministic policy until `episodes` episodes finish; the server's summaries.
pub async fn evaluate(
    client: &EnvClient,
    cfg: &TrainConfig,
    policy: ActorPolicy,
    episodes: usize,
) -> Result<Vec<EpisodeSummary>, EnvError> {
    evaluate_observed(client, cfg, policy, episodes, &mut Unobserved).await
}

/// [`evaluate`], with a video of the evaluation written to `path` (instances tiled).
pub async fn evaluate_recorded(
    client: &EnvClient,
    cfg: &TrainConfig,
    policy: ActorPolicy,
    episodes: usize,
    path: &Path,
    video: &VideoOptions,
) -> Result<(Vec<EpisodeSummary>, VideoReport), crate::report::video::VideoError> {
    let spec = probe_spec(client, cfg).await?;
    let objectives = spec.objectives.iter().map(|o| o.name.clone()).collect();
    let num_envs = episodes.clamp(1, cfg.env.num_envs.max(1));
    let mut recorder = Recorder::new(path, video.clone(), objectives, num_envs)?;
    let done = evaluate_observed(client, cfg, policy, episodes, &mut recorder).await?;
    Ok((done, recorder.finish()?))
}

/// The evaluation loop, reporting to `observer`.
pub async fn evaluate_observed<O: EvalObserver>(
    client: &EnvClient,
    cfg: &TrainConfig,
    policy: ActorPolicy,
    episodes: usize,
    observer: &mut O,
) -> Result<Vec<EpisodeSummary>, O::Error> {
    let num_envs = episodes.clamp(1, cfg.env.num_envs.max(1));
    // Seeds disjoint from the training sessions'.
    let mut env = client
        .make(&make_options(cfg, num_envs, cfg.seed + 1_000_000))
        .await?;
    env.use_stream();
    // `move` takes the policy into the future (a borrowed libtorch module would make
    // it unsendable) and `env` by mutable reference, so that it can be closed below.
    let env_in = &mut env;
    let result: Result<Vec<EpisodeSummary>, O::Error> = async move {
        let env = env_in;
        let map = ActionMap::new(&env.spec().action_space)?;
        let o = env.spec().observation_space.flat_dim();
        let mut obs = env.reset(&[], &[]).await?.observation.to_flat_f32();
        observer.on_reset(env).await?;
        let mut done = Vec::new();
        while done.len() < episodes {
            let obs_t = Tensor::from_slice(&obs).view([num_envs as i64, o as i64]);
            let out = policy.act(&obs_t, Acting::Deterministic);
            let (action, _) = map.apply(&out.actions, num_envs);
            let step = env.step(&action).await?;
            observer.on_step(env, &step).await?;
            done.extend(step.episodes);
            obs = step.observation.to_flat_f32();
        }
        done.truncate(episodes);
        Ok(done)
    }
    .await;
    // Closed on every way out, so a failed evaluation leaves no session behind; an
    // error of the evaluation itself is the one reported.
    match (result, env.close().await) {
        (Ok(done), Ok(())) => Ok(done),
        (Ok(_), Err(e)) => Err(e.into()),
        (Err(e), _) => Err(e),
    }
}

/// What `agent eval` reports.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct EvalReport {
    /// The checkpoint evaluated.
    pub checkpoint: PathBuf,
    /// Objective names in reward order.
    pub objectives: Vec<String>,
    /// The server's per-episode summaries.
    pub episodes: Vec<EpisodeSummary>,
    /// Mean undiscounted return.
    pub mean_return: Vec<f64>,
    /// Mean discounted return.
    pub mean_discounted_return: Vec<f64>,
    /// γ of the discounted returns.
    pub discount: f64,
    /// The video of the evaluation, when one was asked for.
    pub video: Option<VideoReport>,
}

/// The online policy of a checkpoint, on the CPU, with the run it belongs to.
pub struct CheckpointPolicy {
    /// The checkpoint directory read (`checkpoints/step_<n>`).
    pub checkpoint: PathBuf,
    /// The run's resolved `config.toml`.
    pub config: TrainConfig,
    /// The sizes the learner was built for.
    pub dims: LearnerDims,
    /// The policy, with the checkpoint's parameters; an ε-conditioned one acts at
    /// its grid's default point (`with_epsilon` picks another).
    pub policy: ActorPolicy,
    /// The preference grid of an ε-conditioned policy.
    pub grid: Option<PreferenceGrid>,
}

impl CheckpointPolicy {
    /// An ε-conditioned policy acting at `epsilon` (objective name -> ε of the
    /// conditioned objectives; the others keep the grid's first value); an error for a
    /// policy that is not conditioned or a name that is not a conditioned objective.
    pub fn with_epsilon(mut self, epsilon: &BTreeMap<String, f64>) -> Result<Self, EvalError> {
        let bad = |requirement: String| ConfigError::Invalid {
            field: "--epsilon".into(),
            requirement,
            got: format!("{epsilon:?}"),
        };
        let grid = self.grid.as_ref().ok_or_else(|| {
            bad("given only for an ε-conditioned policy (learner.conditioning); this checkpoint's policy has its ε fixed".into())
        })?;
        let eps = grid.epsilon_for(epsilon).map_err(|why| {
            bad(format!(
                "conditioned objectives, each with an ε > 0 ({why})"
            ))
        })?;
        self.policy = self.policy.at_preference(&grid.features_of(&eps));
        Ok(self)
    }
}

/// Load the policy of a checkpoint: a run directory (its latest checkpoint) or one
/// `checkpoints/step_<n>` directory of a run.
pub fn load_checkpoint_policy(path: &Path) -> Result<CheckpointPolicy, EvalError> {
    let (run_dir, ckpt) = if path.join("checkpoints").join("latest.json").exists() {
        (path.to_path_buf(), latest_checkpoint(path)?.0)
    } else {
        let run_dir = path
            .parent()
            .and_then(Path::parent)
            .map(Path::to_path_buf)
            .unwrap_or_default();
        (run_dir, path.to_path_buf())
    };
    // A checkpoint folder outside a run folder has no config beside it: say so,
    // rather than read whatever config.toml the working directory holds.
    let config_path = run_dir.join("config.toml");
    if run_dir.as_os_str().is_empty() || !config_path.is_file() {
        return Err(ConfigError::Invalid {
            field: "--checkpoint".into(),
            requirement: format!(
                "a run folder, or a checkpoint in <run>/checkpoints/, whose run folder holds config.toml (looked for {})",
                config_path.display()
            ),
            got: path.display().to_string(),
        }
        .into());
    }
    let config = TrainConfig::load(&config_path)?;
    let learner = Learner::load_checkpoint(&ckpt, Device::Cpu)?;
    let dims = learner.dims().clone();
    let mut policy = ActorPolicy::new(&config.learner.network, &dims, Device::Cpu);
    policy
        .load(&learner.policy_snapshot())
        .map_err(|e| EvalError::Snapshot(e.to_string()))?;
    let grid = learner.preference_grid().cloned();
    if let Some(grid) = &grid {
        policy = policy.at_preference(&grid.default_features());
    }
    Ok(CheckpointPolicy {
        checkpoint: ckpt,
        config,
        dims,
        policy,
        grid,
    })
}

/// Evaluate a checkpoint (a run directory, meaning its latest checkpoint, or one
/// `checkpoints/step_<n>` directory) with the deterministic policy, against
/// `addresses` reached as `connection` says (not the run's own `env.connection`: the
/// servers may differ), recording a video to `video`'s path when given.
pub async fn evaluate_checkpoint(
    path: &Path,
    addresses: &[String],
    connection: &ConnectionConfig,
    episodes: usize,
    video: Option<(&Path, &VideoOptions)>,
) -> Result<EvalReport, EvalError> {
    evaluate_checkpoint_at(path, None, addresses, connection, episodes, video).await
}

/// [`evaluate_checkpoint`] of an ε-conditioned policy at the preference `epsilon`
/// (objective name -> ε; `None`: the grid's default point, see
/// `PreferenceGrid::default_point`).
pub async fn evaluate_checkpoint_at(
    path: &Path,
    epsilon: Option<&BTreeMap<String, f64>>,
    addresses: &[String],
    connection: &ConnectionConfig,
    episodes: usize,
    video: Option<(&Path, &VideoOptions)>,
) -> Result<EvalReport, EvalError> {
    let mut loaded = load_checkpoint_policy(path)?;
    if let Some(epsilon) = epsilon {
        loaded = loaded.with_epsilon(epsilon)?;
    }
    let CheckpointPolicy {
        checkpoint: ckpt,
        config: cfg,
        policy,
        ..
    } = loaded;
    let client = ServerPool::connect(addresses, connection)
        .await?
        .first()
        .client;
    let spec = probe_spec(&client, &cfg).await?;
    let (done, video) = match video {
        Some((out, options)) => {
            let (done, report) =
                evaluate_recorded(&client, &cfg, policy, episodes, out, options).await?;
            (done, Some(report))
        }
        None => (evaluate(&client, &cfg, policy, episodes).await?, None),
    };
    Ok(EvalReport {
        checkpoint: ckpt,
        objectives: spec.objectives.iter().map(|o| o.name.clone()).collect(),
        mean_return: mean_of(done.iter().map(|e| &e.episode_return)),
        mean_discounted_return: mean_of(done.iter().map(|e| &e.discounted_return)),
        discount: spec.discount,
        episodes: done,
        video,
    })
}
