//! The MO-MPO learner (Algorithm 3), also running scalarized MPO (one critic on
//! `sum_k w_k r_k`, one epsilon) through the same code.
//!
//! One `step` on a `SnippetBatch` of B snippets of length T does, in order:
//! 1. **Policy evaluation** (C.2, eq. 15). The target policy draws M actions at each of
//!    the N = (T+1)B states (all A actions for categorical policies) and the target
//!    critic scores them: `Q' [M, N, C]`. V(s) is their mean (pi_old-weighted sum for
//!    categorical). Retrace targets for the T*B taken pairs use the target critic, the
//!    target policy's log-probabilities and c = min(1, pi_old/b). The online critic is
//!    regressed on them (0.5 * squared error, mean over pairs, summed over heads), one
//!    Adam step.
//! 2. **E-step** (eqs. 32-34) on the same N states and samples: Q_k is the target
//!    critic's head for learned objectives and `-||a||_2` for the action norm; weights
//!    q_k and the temperature duals (`estep.rs`).
//! 3. **M-step** (eqs. 16-20): weighted maximum likelihood with the decoupled trust
//!    region (`mstep.rs`); one Adam step on the policy and one on all duals, then the
//!    dual floor (`dual.rs`).
//! 4. Every `target_update_period` steps the target networks are copied from the online ones.
//!
//! Shape legend: T snippet length, B snippets, N = (T+1)B states, M samples, D action
//! dims, A discrete actions, K objectives, C critics.

use super::adam::{Adam, AdamConfig};
use super::batch::{BatchError, SnippetBatch};
use super::dual::Duals;
use super::estep::{EStepOutput, exact_estep, sampled_estep};
use super::mstep::{TrustRegion, categorical_mstep, gaussian_mstep};
use super::objectives::{BoundObjectives, LearnerDims, QSource, bind_config};
pub use super::stats::{LearnerStats, PhaseTimings};
use super::retrace::{RetraceInputs, importance_weights, retrace_targets};
use crate::config::{ConfigError, LearnerConfig};
use crate::device::synchronize;
use crate::nets::{ActOutput, ActionKind, MultiCritic, Policy, PolicyOutput, PolicySnapshot};
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

/// The MO-MPO / scalarized MPO learner: networks, targets, optimizers, duals, counter.
#[derive(Debug)]
pub struct MoMpoLearner {
    pub(crate) cfg: LearnerConfig,
    pub(crate) dims: LearnerDims,
    pub(crate) bound: BoundObjectives,
    pub(crate) device: Device,
    pub(crate) policy_vs: nn::VarStore,
    policy: Policy,
    pub(crate) target_policy_vs: nn::VarStore,
    target_policy: Policy,
    pub(crate) critic_vs: nn::VarStore,
    critic: MultiCritic,
    pub(crate) target_critic_vs: nn::VarStore,
    target_critic: MultiCritic,
    pub(crate) policy_opt: Adam,
    pub(crate) critic_opt: Adam,
    pub(crate) duals: Duals,
    epsilon: Tensor,
    critic_reward_weights: Tensor,
    pub(crate) step: u64,
}

fn to_vec(t: &Tensor) -> Vec<f32> {
    Vec::<f32>::try_from(
        &t.detach()
            .to_device(Device::Cpu)
            .to_kind(Kind::Float)
            .flatten(0, -1),
    )
    .unwrap_or_default()
}

fn ms_since(start: Instant, device: Device) -> f64 {
    synchronize(device);
    start.elapsed().as_secs_f64() * 1e3
}

impl MoMpoLearner {
    /// Builds networks (seeded by `cfg.seed`), target copies, optimizers and duals.
    pub fn new(
        cfg: LearnerConfig,
        dims: LearnerDims,
        device: Device,
    ) -> Result<Self, LearnerError> {
        let bound = bind_config(&cfg, &dims)?;
        tch::manual_seed(cfg.seed as i64);
        let net = &cfg.network;
        let heads = bound.critic_names.len() as i64;
        let policy_vs = nn::VarStore::new(device);
        let policy = Policy::new(
            &(policy_vs.root() / "policy"),
            net,
            dims.obs_dim,
            dims.action,
        );
        let (target_policy_vs, target_policy) = frozen_copy(&policy_vs, |vs| {
            Policy::new(&(vs.root() / "policy"), net, dims.obs_dim, dims.action)
        })?;
        let critic_vs = nn::VarStore::new(device);
        let critic = MultiCritic::new(
            &(critic_vs.root() / "critic"),
            net,
            dims.obs_dim,
            dims.action,
            heads,
        );
        let (target_critic_vs, target_critic) = frozen_copy(&critic_vs, |vs| {
            MultiCritic::new(&(vs.root() / "critic"), net, dims.obs_dim, dims.action, heads)
        })?;
        let mpo = &cfg.mpo;
        let adam = AdamConfig::new(mpo.learning_rate, mpo.adam_eps);
        let policy_opt = Adam::for_var_store(&policy_vs, adam);
        let critic_opt = Adam::for_var_store(&critic_vs, adam);
        let temperatures = vec![mpo.init_temperature; bound.objectives.len()];
        let alphas = match dims.action {
            ActionKind::Continuous { .. } => vec![mpo.init_alpha_mean, mpo.init_alpha_cov],
            ActionKind::Discrete { .. } => vec![mpo.init_alpha_categorical],
        };
        let duals = Duals::new(&temperatures, &alphas, mpo.dual_learning_rate, device);
        let eps: Vec<f32> = bound.objectives.iter().map(|o| o.epsilon as f32).collect();
        let epsilon = Tensor::from_slice(&eps).to_device(device);
        let w: Vec<f32> = bound
            .critic_reward_weights
            .iter()
            .flatten()
            .map(|&w| w as f32)
            .collect();
        let critic_reward_weights = Tensor::from_slice(&w)
            .reshape([dims.reward_names.len() as i64, heads])
            .to_device(device);
        Ok(Self {
            cfg,
            dims,
            bound,
            device,
            policy_vs,
            policy,
            target_policy_vs,
            target_policy,
            critic_vs,
            critic,
            target_critic_vs,
            target_critic,
            policy_opt,
            critic_opt,
            duals,
            epsilon,
            critic_reward_weights,
            step: 0,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &LearnerConfig {
        &self.cfg
    }

    /// The dimensions the learner was built for.
    pub fn dims(&self) -> &LearnerDims {
        &self.dims
    }

    /// Bound objectives (E-step order) and critic heads.
    pub fn objectives(&self) -> &BoundObjectives {
        &self.bound
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
    /// # Shapes
    /// `obs [B, O]` -> actions `[B, D]` f32 or `[B]` i64, log-probs `[B]`.
    pub fn act(&self, obs: &Tensor, deterministic: bool) -> ActOutput {
        self.policy.act(&obs.to_device(self.device), deterministic)
    }

    /// Copy of the online policy parameters for actors.
    pub fn policy_snapshot(&self) -> PolicySnapshot {
        PolicySnapshot::from_var_store(&self.policy_vs)
    }

    /// Q-values for the E-step, `[M, N, K]`, from critic heads and closed forms.
    fn estep_q(&self, critic_q: &Tensor, actions: &Tensor) -> Tensor {
        let columns: Vec<Tensor> = self
            .bound
            .objectives
            .iter()
            .map(|o| match o.source {
                QSource::Critic { head } => critic_q.select(-1, head as i64),
                QSource::ActionNorm => -actions
                    .square()
                    .sum_dim_intlist(-1, false, Kind::Float)
                    .sqrt(),
            })
            .collect();
        Tensor::stack(&columns, -1)
    }

    /// One learner step (critic update, E-step, M-step, duals, target update).
    pub fn step(&mut self, batch: &SnippetBatch) -> Result<LearnerStats, LearnerError> {
        batch.check(
            self.dims.obs_dim,
            self.dims.action,
            self.dims.reward_names.len() as i64,
        )?;
        let start = Instant::now();
        let batch = batch.to_device(self.device);
        let (t_len, b) = (batch.len(), batch.batch_size());
        let n = (t_len + 1) * b;
        let obs_all = batch.observations.reshape([n, self.dims.obs_dim]);
        let obs_taken = obs_all.narrow(0, 0, t_len * b);
        let act_taken = batch.actions.flatten(0, 1);
        let heads = self.bound.critic_names.len() as i64;

        // 1. Policy evaluation with Retrace (C.2).
        let eval = tch::no_grad(|| {
            let target_out = self.target_policy.forward(&obs_all);
            let (samples, critic_q, v_all, log_prior) = match &target_out {
                PolicyOutput::Gaussian(g) => {
                    let samples = g.sample(self.cfg.mpo.num_samples);
                    let q = self.target_critic.forward_samples(&obs_all, &samples);
                    let v = q.mean_dim(0, false, Kind::Float);
                    (samples, q, v, None)
                }
                PolicyOutput::Categorical(logits) => {
                    let q = self.target_critic.forward_all_actions(&obs_all);
                    let log_prior = logits.log_softmax(-1, Kind::Float).transpose(0, 1);
                    let v =
                        (log_prior.exp().unsqueeze(-1) * &q).sum_dim_intlist(0, false, Kind::Float);
                    let a = logits.size()[1];
                    let all = Tensor::arange(a, (Kind::Int64, self.device))
                        .unsqueeze(1)
                        .expand([a, n], false);
                    (all, q, v, Some(log_prior))
                }
            };
            let v_next = v_all.reshape([t_len + 1, b, heads]).narrow(0, 1, t_len);
            let q_taken = self
                .target_critic
                .forward(&obs_taken, &act_taken)
                .reshape([t_len, b, heads]);
            let target_log_probs = match &target_out {
                PolicyOutput::Gaussian(g) => PolicyOutput::Gaussian(crate::nets::GaussianParams {
                    mean: g.mean.narrow(0, 0, t_len * b),
                    std: g.std.narrow(0, 0, t_len * b),
                }),
                PolicyOutput::Categorical(l) => {
                    PolicyOutput::Categorical(l.narrow(0, 0, t_len * b))
                }
            }
            .log_prob(&act_taken)
            .reshape([t_len, b]);
            let importance = importance_weights(&target_log_probs, &batch.behaviour_log_probs);
            let rewards = batch.rewards.matmul(&self.critic_reward_weights);
            let targets = retrace_targets(&RetraceInputs {
                q_taken: &q_taken,
                v_next: &v_next,
                rewards: &rewards,
                discounts: &batch.discounts,
                importance: &importance,
                gamma: self.cfg.mpo.discount,
            });
            (
                target_out,
                samples,
                critic_q,
                log_prior,
                targets.reshape([t_len * b, heads]),
            )
        });
        let (target_out, samples, critic_q, log_prior, targets) = eval;
        let q_online = self.critic.forward(&obs_taken, &act_taken);
        let per_head = (q_online - &targets)
            .square()
            .mean_dim(0, false, Kind::Float)
            * 0.5;
        self.critic_opt.zero_grad();
        per_head.sum(Kind::Float).backward();
        if let Some(max) = self.cfg.mpo.grad_clip_norm {
            self.critic_opt.clip_grad_norm(max);
        }
        self.critic_opt.step();
        let policy_evaluation_ms = ms_since(start, self.device);

        // 2. E-step (eqs. 32-34).
        let start = Instant::now();
        let q = self.estep_q(&critic_q, &samples);
        let temperature = self.duals.temperature();
        let estep: EStepOutput = match &log_prior {
            None => sampled_estep(&q, &temperature, &self.epsilon),
            Some(prior) => exact_estep(&q, prior, &temperature, &self.epsilon),
        };
        let weights = estep.weights.sum_dim_intlist(-1, false, Kind::Float);
        let e_step_ms = ms_since(start, self.device);

        // 3. M-step (eqs. 16-20) and dual updates.
        let start = Instant::now();
        let alpha = self.duals.alpha();
        let online_out = self.policy.forward(&obs_all);
        let (policy_loss, alpha_loss, policy_kl) = match (&online_out, &target_out) {
            (PolicyOutput::Gaussian(online), PolicyOutput::Gaussian(target)) => {
                let (alpha_mean, alpha_cov) = (alpha.get(0), alpha.get(1));
                let region = TrustRegion {
                    alpha_mean: &alpha_mean,
                    alpha_cov: &alpha_cov,
                    beta_mean: self.cfg.mpo.beta_mean,
                    beta_cov: self.cfg.mpo.beta_cov,
                };
                let out = gaussian_mstep(online, target, &samples, &weights, &region);
                (
                    out.policy_loss,
                    out.alpha_loss,
                    Tensor::stack(&[out.kl_mean, out.kl_cov], 0),
                )
            }
            (PolicyOutput::Categorical(online), PolicyOutput::Categorical(target)) => {
                let out = categorical_mstep(
                    online,
                    target,
                    &weights,
                    &alpha.get(0),
                    self.cfg.mpo.beta_categorical,
                );
                (out.policy_loss, out.alpha_loss, out.kl.unsqueeze(0))
            }
            _ => unreachable!("online and target policies have the same kind"),
        };
        self.policy_opt.zero_grad();
        self.duals.zero_grad();
        (policy_loss + alpha_loss + &estep.temperature_loss).backward();
        if let Some(max) = self.cfg.mpo.grad_clip_norm {
            self.policy_opt.clip_grad_norm(max);
        }
        self.policy_opt.step();
        self.duals.step();
        let m_step_ms = ms_since(start, self.device);

        // 4. Target networks.
        let start = Instant::now();
        self.step += 1;
        if self.step.is_multiple_of(self.cfg.mpo.target_update_period) {
            self.target_policy_vs.copy(&self.policy_vs)?;
            self.target_critic_vs.copy(&self.critic_vs)?;
        }
        let target_update_ms = ms_since(start, self.device);
        let (temperature, alpha) = self.duals.values();
        Ok(LearnerStats {
            step: self.step,
            critic_loss: to_vec(&per_head),
            temperature,
            estep_kl: to_vec(&estep.kl),
            q_mean: to_vec(&q.mean_dim([0i64, 1].as_slice(), false, Kind::Float)),
            alpha,
            policy_kl: to_vec(&policy_kl),
            timings: PhaseTimings {
                policy_evaluation_ms,
                e_step_ms,
                m_step_ms,
                target_update_ms,
            },
        })
    }

    /// Policy improvement only (E-step, M-step, duals) on given Q-values of the target
    /// policy's samples, for bandits and tests where Q is known in closed form.
    /// `q_fn` maps sampled actions `[M, N, D]` to Q `[M, N, K]`.
    /// Returns (temperatures, policy KL (KL_mu, KL_Sigma) before the update).
    pub fn improve_policy_with(
        &mut self,
        obs: &Tensor,
        q_fn: impl Fn(&Tensor) -> Tensor,
    ) -> (Vec<f32>, Vec<f32>) {
        let obs = obs.to_device(self.device);
        let target_out = tch::no_grad(|| self.target_policy.forward(&obs));
        let PolicyOutput::Gaussian(target) = &target_out else {
            panic!("improve_policy_with needs a Gaussian policy");
        };
        let samples = tch::no_grad(|| target.sample(self.cfg.mpo.num_samples));
        let q = q_fn(&samples);
        let estep = sampled_estep(&q, &self.duals.temperature(), &self.epsilon);
        let alpha = self.duals.alpha();
        let PolicyOutput::Gaussian(online) = self.policy.forward(&obs) else {
            unreachable!()
        };
        let (alpha_mean, alpha_cov) = (alpha.get(0), alpha.get(1));
        let region = TrustRegion {
            alpha_mean: &alpha_mean,
            alpha_cov: &alpha_cov,
            beta_mean: self.cfg.mpo.beta_mean,
            beta_cov: self.cfg.mpo.beta_cov,
        };
        let out = gaussian_mstep(
            &online,
            target,
            &samples,
            &estep.weights.sum_dim_intlist(-1, false, Kind::Float),
            &region,
        );
        self.policy_opt.zero_grad();
        self.duals.zero_grad();
        (out.policy_loss + out.alpha_loss + estep.temperature_loss).backward();
        self.policy_opt.step();
        self.duals.step();
        self.step += 1;
        if self.step.is_multiple_of(self.cfg.mpo.target_update_period) {
            self.target_policy_vs
                .copy(&self.policy_vs)
                .expect("same layout");
        }
        (
            self.duals.values().0,
            to_vec(&Tensor::stack(&[out.kl_mean, out.kl_cov], 0)),
        )
    }
}
