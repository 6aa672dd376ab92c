//! The learner's state: networks and their targets, Adam optimizers, the duals
//! (eta_k, alpha), the bound objectives and the preference grid, built from a config;
//! the optimizer steps that change them are `update.rs`.
//!
//! One `Learner` runs any of the four algorithms; `step` is the one `match` over the
//! two families: MO-MPO / scalarized MPO (`mompo.rs`, Q critics with targets) and
//! MO-V-MPO / scalarized V-MPO (`movmpo.rs`, state-value critics).
//!
//! Shape legend: N states, M samples (or A actions), D action dims, K objectives,
//! C learned critics.

use super::adam::{Adam, AdamConfig};
use super::batch::{BatchError, SnippetBatch};
use super::dual::Duals;
use super::mstep::KlConstraint;
use super::noise::{NoiseError, NoiseSource};
use super::objectives::{BoundObjectives, LearnerDims, bind_config};
use super::preferences::{Conditioned, PreferenceGrid};
pub use super::stats::{LearnerStats, PhaseTimings};
use crate::config::{ConfigError, LearnerConfig, SharedSettings};
use crate::device::synchronize;
use crate::nets::{
    ActOutput, Acting, ActionKind, MultiCritic, Policy, PolicySnapshot, SnapshotError, ValueNet,
};
use crate::random::{Purpose, RandomStream, StreamKey, seeded_init};
use std::cell::Cell;
use std::time::Instant;
use tch::{Device, Kind, Tensor, nn};

/// Errors of constructing or stepping the learner.
#[derive(Debug, thiserror::Error)]
pub enum LearnerError {
    /// Invalid configuration or objective binding.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// A batch that does not fit.
    #[error(transparent)]
    Batch(#[from] BatchError),
    /// libtorch failed.
    #[error("libtorch: {0}")]
    Torch(#[from] tch::TchError),
    /// Given sampling noise does not fit the step.
    #[error(transparent)]
    Noise(#[from] NoiseError),
    /// Given parameters do not fit the networks.
    #[error(transparent)]
    Parameters(#[from] SnapshotError),
}

/// A target network (C.1): same layout as `online`'s network, built by `build` on a new
/// VarStore on the same device, parameters copied, frozen (no gradients).
fn frozen_copy<N>(
    online: &nn::VarStore,
    build: impl FnOnce(&nn::VarStore) -> N,
) -> Result<(nn::VarStore, N), tch::TchError> {
    let mut vs = nn::VarStore::new(online.device());
    let net = build(&vs);
    vs.copy(online)?;
    vs.freeze();
    Ok((vs, net))
}

/// The critics of either family.
#[derive(Debug)]
#[allow(
    clippy::large_enum_variant,
    reason = "one per learner; boxing buys nothing"
)]
pub(crate) enum Critics {
    /// MO-MPO: Q_c(s, a) with a frozen target copy (C.1).
    Q {
        online: MultiCritic,
        target: MultiCritic,
        target_vs: nn::VarStore,
    },
    /// MO-V-MPO: V_c(s), bootstrapped from itself (D.1).
    V { online: ValueNet },
}

/// What `Learner::build_networks` makes.
struct Networks {
    policy_vs: nn::VarStore,
    policy: Policy,
    target_policy_vs: nn::VarStore,
    target_policy: Policy,
    critic_vs: nn::VarStore,
    critics: Critics,
}

/// Networks, targets, optimizers, duals and the step counter of one learner.
#[derive(Debug)]
pub struct Learner {
    pub(crate) cfg: LearnerConfig,
    pub(crate) settings: SharedSettings,
    pub(crate) dims: LearnerDims,
    pub(crate) bound: BoundObjectives,
    pub(crate) device: Device,
    pub(crate) policy_vs: nn::VarStore,
    pub(crate) policy: Policy,
    pub(crate) target_policy_vs: nn::VarStore,
    pub(crate) target_policy: Policy,
    pub(crate) critic_vs: nn::VarStore,
    pub(crate) critics: Critics,
    pub(crate) policy_opt: Adam,
    pub(crate) critic_opt: Adam,
    pub(crate) duals: Duals,
    /// `[K]`: epsilon_k of the bound objectives.
    pub(crate) epsilon: Tensor,
    /// `[K_env, C]`: which reward each critic head learns.
    pub(crate) critic_reward_weights: Tensor,
    /// The preference grid of an ε-conditioned learner; its temperatures are then
    /// `[G * K]`, grid point by grid point.
    pub(crate) conditioned: Option<Conditioned>,
    /// Where the sampled actions' noise comes from.
    pub(crate) noise: NoiseSource,
    /// Sampling `act` calls so far: the counter of the `LearnerActing` stream.
    acts: Cell<u64>,
    pub(crate) step: u64,
}

pub(crate) fn to_vec(t: &Tensor) -> Vec<f32> {
    Vec::<f32>::try_from(
        &t.detach()
            .to_device(Device::Cpu)
            .to_kind(Kind::Float)
            .flatten(0, -1),
    )
    .unwrap_or_default()
}

pub(crate) fn ms_since(start: Instant, device: Device) -> f64 {
    synchronize(device);
    start.elapsed().as_secs_f64() * 1e3
}

impl Learner {
    /// Builds networks (seeded by `cfg.seed`), target copies, optimizers and duals.
    pub fn new(
        cfg: LearnerConfig,
        dims: LearnerDims,
        device: Device,
    ) -> Result<Self, LearnerError> {
        let bound = bind_config(&cfg, &dims)?;
        let settings = cfg.shared();
        let nets = seeded_init(cfg.seed, || {
            Self::build_networks(&cfg, &dims, &bound, device)
        })?;
        let Networks {
            policy_vs,
            policy,
            target_policy_vs,
            target_policy,
            critic_vs,
            critics,
        } = nets;
        let adam = AdamConfig::new(settings.learning_rate, settings.adam_eps);
        let policy_opt = Adam::for_var_store(&policy_vs, adam);
        let critic_opt = Adam::for_var_store(&critic_vs, adam);
        let conditioned = cfg
            .conditioning
            .as_ref()
            .map(|c| Conditioned::new(c, &bound, &dims, device))
            .transpose()?;
        let grid_points = conditioned.as_ref().map_or(1, |c| c.grid.len());
        let temperatures = vec![settings.init_temperature; grid_points * bound.objectives.len()];
        let alphas: Vec<Vec<f64>> = match dims.action {
            ActionKind::Continuous { dim } => {
                let per_part = match settings.kl_constraint {
                    KlConstraint::Summed => 1,
                    KlConstraint::PerDimension => dim as usize,
                };
                vec![
                    vec![settings.init_alpha_mean; per_part],
                    vec![settings.init_alpha_cov; per_part],
                ]
            }
            ActionKind::Discrete { .. } => vec![vec![settings.init_alpha_categorical]],
        };
        let alpha_parts: Vec<&[f64]> = alphas.iter().map(Vec::as_slice).collect();
        let duals = Duals::new(
            &temperatures,
            &alpha_parts,
            settings.dual_learning_rate,
            settings.temperature_parameterization,
            device,
        );
        let eps: Vec<f32> = bound.objectives.iter().map(|o| o.epsilon as f32).collect();
        let epsilon = Tensor::from_slice(&eps).to_device(device);
        let w: Vec<f32> = bound
            .critic_reward_weights
            .iter()
            .flatten()
            .map(|&w| w as f32)
            .collect();
        let heads = bound.critic_names.len() as i64;
        let critic_reward_weights = Tensor::from_slice(&w)
            .reshape([dims.reward_names.len() as i64, heads])
            .to_device(device);
        let noise = NoiseSource::Draw(StreamKey::new(cfg.seed, Purpose::LearnerNoise, 0));
        Ok(Self {
            cfg,
            settings,
            dims,
            bound,
            device,
            policy_vs,
            policy,
            target_policy_vs,
            target_policy,
            critic_vs,
            critics,
            policy_opt,
            critic_opt,
            duals,
            epsilon,
            critic_reward_weights,
            conditioned,
            noise,
            acts: Cell::new(0),
            step: 0,
        })
    }

    /// The networks in today's construction order, which fixes what each parameter
    /// draws from the seeded generator (see `random::seeded_init`).
    fn build_networks(
        cfg: &LearnerConfig,
        dims: &LearnerDims,
        bound: &BoundObjectives,
        device: Device,
    ) -> Result<Networks, tch::TchError> {
        let net = &cfg.network;
        let heads = bound.critic_names.len() as i64;
        let policy_vs = nn::VarStore::new(device);
        let policy = Policy::new(&(policy_vs.root() / "policy"), net, dims);
        let (target_policy_vs, target_policy) = frozen_copy(&policy_vs, |vs| {
            Policy::new(&(vs.root() / "policy"), net, dims)
        })?;
        let critic_vs = nn::VarStore::new(device);
        let critics = if cfg.algorithm.on_policy() {
            Critics::V {
                online: ValueNet::new(&(critic_vs.root() / "critic"), net, dims.obs_dim, heads),
            }
        } else {
            let build = |vs: &nn::VarStore| {
                MultiCritic::new(
                    &(vs.root() / "critic"),
                    net,
                    dims.obs_dim,
                    dims.action,
                    heads,
                )
            };
            let online = build(&critic_vs);
            let (target_vs, target) = frozen_copy(&critic_vs, build)?;
            Critics::Q {
                online,
                target,
                target_vs,
            }
        };
        Ok(Networks {
            policy_vs,
            policy,
            target_policy_vs,
            target_policy,
            critic_vs,
            critics,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &LearnerConfig {
        &self.cfg
    }

    /// The hyperparameters of this algorithm family (batch size, sequence length, ...).
    pub fn settings(&self) -> &SharedSettings {
        &self.settings
    }

    /// The dimensions the learner was built for.
    pub fn dims(&self) -> &LearnerDims {
        &self.dims
    }

    /// The preference grid, when the learner is ε-conditioned.
    pub fn preference_grid(&self) -> Option<&PreferenceGrid> {
        self.conditioned.as_ref().map(|c| &c.grid)
    }

    /// Bound objectives (E-step order) and critic heads.
    pub fn objectives(&self) -> &BoundObjectives {
        &self.bound
    }

    /// The trust-region multipliers, per part (alpha_mu, alpha_Sigma; or alpha): one
    /// value each, or one per action dimension with a per-dimension KL constraint.
    /// `LearnerStats::alpha` reports each part's mean.
    pub fn alpha_by_part(&self) -> Vec<Vec<f32>> {
        self.duals.alpha_by_part()
    }

    /// Replaces the source of the sampling noise (by default drawn afresh), e.g. with
    /// given tensors that a reference implementation uses too.
    pub fn set_noise_source(&mut self, source: NoiseSource) {
        self.noise = source;
    }

    /// Learner steps done.
    pub fn step_count(&self) -> u64 {
        self.step
    }

    /// Device of the networks.
    pub fn device(&self) -> Device {
        self.device
    }

    /// Actions from the online policy (sampled, or the mode with `deterministic`).
    /// Samples come from the learner's `LearnerActing` stream, one counter per call.
    /// # Shapes
    /// `obs [B, O]` -> actions `[B, D]` f32 or `[B]` i64, log-probs `[B]`.
    pub fn act(&self, obs: &Tensor, deterministic: bool) -> ActOutput {
        let obs = obs.to_device(self.device);
        if deterministic {
            return self.policy.act(&obs, Acting::Deterministic);
        }
        let call = self.acts.replace(self.acts.get() + 1);
        let mut stream = StreamKey::new(self.cfg.seed, Purpose::LearnerActing, 0).at(call);
        self.policy.act(&obs, Acting::Sample(&mut stream))
    }

    /// This learner step's stream for `purpose` (keyed by `learner.seed`).
    pub(crate) fn stream(&self, purpose: Purpose) -> RandomStream {
        StreamKey::new(self.cfg.seed, purpose, 0).at(self.step)
    }

    /// Copy of the online policy parameters for actors.
    pub fn policy_snapshot(&self) -> PolicySnapshot {
        PolicySnapshot::from_var_store(&self.policy_vs)
    }

    /// One learner step of the configured algorithm on B sequences of T steps.
    pub fn step(&mut self, batch: &SnippetBatch) -> Result<LearnerStats, LearnerError> {
        batch.check(
            self.dims.obs_dim,
            self.dims.action,
            self.dims.reward_names.len() as i64,
        )?;
        if self.cfg.algorithm.on_policy() {
            self.vmpo_step(batch)
        } else {
            self.mpo_step(batch)
        }
    }
}
