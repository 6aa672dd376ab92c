//! The learner's state: networks and their targets, Adam optimizers, the duals
//! (eta_k, alpha), the bound objectives and the preference grid, built from a config;
//! the optimizer steps that change them are `update.rs`.
//!
//! One `Learner` runs any of the four algorithms; `step` is the one `match` over the
//! two families: MO-MPO / scalarized MPO (`mompo.rs`, Q critics with targets) and
//! MO-V-MPO / scalarized V-MPO (`movmpo.rs`, state-value critics).
//!
//! **Populations** (docs/design.md, "Populations"): `Learner::population` trains P members
//! that share algorithm, architecture, batch and pace and differ in seed, ε or
//! scalarization weights as one program: parameters, Adam moments, duals and targets
//! carry a leading member axis (`nets::Members`), the members' losses are summed
//! before one backward (each member gets exactly its own gradient), and each member
//! draws from its own random streams. `Learner::new` is a population of one. Every
//! algorithm; ε-conditioned learners and mocap torsos have one member.
//!
//! Shape legend: P members, N states, M samples (or A actions), D action dims, K
//! objectives, C learned critics.

use super::adam::{Adam, AdamConfig};
use super::batch::{BatchError, SnippetBatch};
use super::dual::{AlphaPart, DualOptimizer, Duals};
use super::mstep::KlConstraint;
pub(crate) use super::networks::Critics;
use super::networks::{Networks, build_member_networks};
use super::noise::{NoiseError, NoiseSource};
use super::objectives::{BoundObjectives, LearnerDims, bind_config};
use super::population::check_population;
use super::preferences::{Conditioned, PreferenceGrid};
pub use super::stats::{LearnerStats, PhaseTimings};
use crate::core::device::synchronize;
use crate::core::learner_config::{ConfigError, GridTrustRegion, LearnerConfig, SharedSettings};
use crate::core::nets::{ActOutput, Acting, ActionKind, Members, PolicySnapshot, SnapshotError};
use crate::core::random::{Purpose, RandomStream, StreamKey};
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

/// Networks, targets, optimizers, duals and the step counter of one learner.
#[derive(Debug)]
pub struct Learner {
    pub(crate) cfg: LearnerConfig,
    pub(crate) settings: SharedSettings,
    pub(crate) dims: LearnerDims,
    pub(crate) bound: BoundObjectives,
    pub(crate) device: Device,
    /// The policy, its target and the critics, with their variable stores.
    pub(crate) nets: Networks,
    pub(crate) policy_opt: Adam,
    pub(crate) critic_opt: Adam,
    pub(crate) duals: Duals,
    /// `[K]` (`[P, K]` stacked): epsilon_k of the bound objectives.
    pub(crate) epsilon: Tensor,
    /// `[K_env, C]` (`[P, K_env, C]` stacked): which reward each critic head learns.
    pub(crate) critic_reward_weights: Tensor,
    /// The preference grid of an ε-conditioned learner; its temperatures are then
    /// `[G * K]`, grid point by grid point.
    pub(crate) conditioned: Option<Conditioned>,
    /// Where each member's sampled actions' noise comes from.
    pub(crate) noise: Vec<NoiseSource>,
    /// How many members; parameters and duals are stacked when more than one.
    pub(crate) members: Members,
    /// Each member's config (`cfg` is the first's).
    pub(crate) member_cfgs: Vec<LearnerConfig>,
    /// `[P]`: the fraction of this step's policy step each member kept after the
    /// trust region's projection (`mpo.max_kl_ratio`); `None` when none ran.
    pub(crate) policy_step_kept: Option<Tensor>,
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

/// The duals at their initial values: `temperatures` eta, and alpha_mu and
/// alpha_Sigma (one each, or one per action dimension with a per-dimension KL
/// constraint; `trust_regions` times that with a per-grid-point trust region) or the
/// categorical alpha, as the action space has them.
fn initial_duals(
    settings: &SharedSettings,
    action: ActionKind,
    counts: DualCounts,
    device: Device,
    members: Members,
) -> Duals {
    let DualCounts {
        temperatures,
        trust_regions,
    } = counts;
    let part = |init: f64, per_part: usize, min: f64| AlphaPart {
        init: vec![init; per_part],
        min,
    };
    let min = settings.min_alpha;
    let alphas = match action {
        ActionKind::Continuous { dim } => {
            let per_part = match settings.kl_constraint {
                KlConstraint::Summed => trust_regions,
                KlConstraint::PerDimension => trust_regions * dim as usize,
            };
            vec![
                part(settings.init_alpha_mean, per_part, min.mean),
                part(settings.init_alpha_cov, per_part, min.cov),
            ]
        }
        ActionKind::Discrete { .. } => {
            vec![part(settings.init_alpha_categorical, 1, min.categorical)]
        }
    };
    Duals::with_members(
        &vec![settings.init_temperature; temperatures],
        &alphas,
        DualOptimizer {
            lr: settings.dual_learning_rate,
            beta2: settings.dual_adam_beta2,
            temperature_kind: settings.temperature_parameterization,
        },
        device,
        members,
    )
}

/// How many multipliers of each kind a learner keeps.
#[derive(Debug, Clone, Copy)]
struct DualCounts {
    /// eta: one per objective (and grid point, when ε-conditioned).
    temperatures: usize,
    /// Sets of trust-region multipliers: one, or one per grid point.
    trust_regions: usize,
}

/// The members' values, member after member, as one tensor of `shape` on `device`.
fn member_tensor(values: impl Iterator<Item = f32>, shape: Vec<i64>, device: Device) -> Tensor {
    let values: Vec<f32> = values.collect();
    Tensor::from_slice(&values)
        .reshape(shape.as_slice())
        .to_device(device)
}

impl Learner {
    /// Builds networks (seeded by `cfg.seed`), target copies, optimizers and duals.
    pub fn new(
        cfg: LearnerConfig,
        dims: LearnerDims,
        device: Device,
    ) -> Result<Self, LearnerError> {
        Self::population(vec![cfg], dims, device)
    }

    /// A population: one member per config. The configs must agree on everything but
    /// `seed`, the objectives' ε and the scalarization weights (`population_key`).
    /// Member p's networks are built as `new` builds them from `cfgs[p]` (same
    /// parameters, bit for bit), then stacked.
    pub fn population(
        cfgs: Vec<LearnerConfig>,
        dims: LearnerDims,
        device: Device,
    ) -> Result<Self, LearnerError> {
        check_population(&cfgs)?;
        let members = Members::new(cfgs.len() as i64).expect("checked: at least one member");
        let cfg = cfgs[0].clone();
        let bounds = cfgs
            .iter()
            .map(|c| bind_config(c, &dims))
            .collect::<Result<Vec<_>, _>>()?;
        let bound = bounds[0].clone();
        let settings = cfg.shared();
        let nets = build_member_networks(&cfgs, &bounds, &dims, device, members)?;
        let adam = |vs: &nn::VarStore, lr: f64| {
            Adam::for_var_store(vs, AdamConfig::new(lr, settings.adam_eps))
        };
        let policy_opt = adam(&nets.policy_vs, settings.policy_learning_rate);
        let critic_opt = adam(&nets.critic_vs, settings.critic_learning_rate);
        let conditioned = cfg
            .conditioning
            .as_ref()
            .map(|c| Conditioned::new(c, &bound, &dims, device))
            .transpose()?;
        // An ε-conditioned learner has one eta per objective and grid point.
        let grid_points = conditioned.as_ref().map_or(1, |c| c.grid.len());
        let counts = DualCounts {
            temperatures: grid_points * bound.objectives.len(),
            trust_regions: match conditioned.as_ref().map(|c| c.trust_region) {
                Some(GridTrustRegion::PerPoint) => grid_points,
                _ => 1,
            },
        };
        let duals = initial_duals(&settings, dims.action, counts, device, members);
        let k = bound.objectives.len() as i64;
        let epsilon = member_tensor(
            bounds
                .iter()
                .flat_map(|b| b.objectives.iter().map(|o| o.epsilon as f32)),
            members.shape(&[k]),
            device,
        );
        let heads = bound.critic_names.len() as i64;
        let critic_reward_weights = member_tensor(
            bounds
                .iter()
                .flat_map(|b| b.critic_reward_weights.iter().flatten().map(|&w| w as f32)),
            members.shape(&[dims.reward_names.len() as i64, heads]),
            device,
        );
        let noise = cfgs
            .iter()
            .map(|c| NoiseSource::Draw(StreamKey::new(c.seed, Purpose::LearnerNoise, 0)))
            .collect();
        Ok(Self {
            cfg,
            settings,
            dims,
            bound,
            device,
            nets,
            policy_opt,
            critic_opt,
            duals,
            epsilon,
            critic_reward_weights,
            conditioned,
            noise,
            members,
            member_cfgs: cfgs,
            policy_step_kept: None,
            acts: Cell::new(0),
            step: 0,
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
    /// given tensors that a reference implementation uses too (every member's: one
    /// source per member).
    pub fn set_noise_source(&mut self, source: NoiseSource) {
        self.set_member_noise_sources(vec![source]);
    }

    /// One noise source per member, in member order (panics on another count).
    pub fn set_member_noise_sources(&mut self, sources: Vec<NoiseSource>) {
        assert_eq!(
            sources.len() as i64,
            self.members.count(),
            "one source per member"
        );
        self.noise = sources;
    }

    /// How many members this learner trains.
    pub fn member_count(&self) -> usize {
        self.members.count() as usize
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
            return self.nets.policy.act(&obs, Acting::Deterministic);
        }
        let call = self.acts.replace(self.acts.get() + 1);
        let mut stream = StreamKey::new(self.cfg.seed, Purpose::LearnerActing, 0).at(call);
        self.nets.policy.act(&obs, Acting::Sample(&mut stream))
    }

    /// This learner step's stream for `purpose` (keyed by `learner.seed`).
    pub(crate) fn stream(&self, purpose: Purpose) -> RandomStream {
        StreamKey::new(self.cfg.seed, purpose, 0).at(self.step)
    }

    /// Copy of the online policy parameters for actors.
    pub fn policy_snapshot(&self) -> PolicySnapshot {
        self.member_policy_snapshot(0)
    }

    /// One learner step of the configured algorithm on B sequences of T steps (a
    /// learner of one member).
    pub fn step(&mut self, batch: &SnippetBatch) -> Result<LearnerStats, LearnerError> {
        let mut stats = self.step_members(std::slice::from_ref(batch))?;
        Ok(stats.swap_remove(0))
    }

    /// One learner step of every member on its own batch (all of one shape); the
    /// statistics in member order.
    pub fn step_members(
        &mut self,
        batches: &[SnippetBatch],
    ) -> Result<Vec<LearnerStats>, LearnerError> {
        if batches.len() as i64 != self.members.count() {
            return Err(BatchError {
                field: "batches",
                expected: format!("one per member ({})", self.members.count()),
                got: batches.len().to_string(),
            }
            .into());
        }
        for batch in batches {
            self.check_batch(batch)?;
            let first = &batches[0];
            if (batch.len(), batch.batch_size()) != (first.len(), first.batch_size()) {
                return Err(BatchError {
                    field: "observations",
                    expected: format!(
                        "the first member's T = {}, B = {}",
                        first.len(),
                        first.batch_size()
                    ),
                    got: format!("T = {}, B = {}", batch.len(), batch.batch_size()),
                }
                .into());
            }
        }
        if self.cfg.algorithm.on_policy() {
            return self.vmpo_step(batches);
        }
        self.mpo_step(batches)
    }

    fn check_batch(&self, batch: &SnippetBatch) -> Result<(), BatchError> {
        batch.check(
            self.dims.obs_dim,
            self.dims.action,
            self.dims.reward_names.len() as i64,
        )
    }
}
