//! The optimizer half of a learner step, shared by both algorithm families: the
//! critic's Adam step, the policy fit under the decoupled trust region (the M-step of
//! eqs. 16-20 for MO-MPO, step 2 of eq. 25 for MO-V-MPO; `mstep.rs` has the losses)
//! with one Adam step on the policy and one on the duals, the target-network
//! schedule (C.1) that ends every step, and the clock of the step's phases.
//!
//! Shape legend: N states, M samples (or A actions), D action dims, K objectives,
//! C learned critics.

use super::estep::StateMean;
use super::mstep::{TrustRegion, categorical_mstep_with, gaussian_mstep_with};
use super::preferences::StatePreferences;
use super::state::{Critics, Learner, LearnerError, LearnerStats, PhaseTimings, ms_since, to_vec};
use crate::core::nets::PolicyOutput;
use std::time::Instant;
use tch::{Device, Kind, Tensor, nn};

/// What a step measured before its target update (tensors on the learner's device).
#[derive(Debug)]
pub(crate) struct StepMeasures {
    /// `[C]` critic losses.
    pub critic_loss: Tensor,
    /// `[K]` realised KL(q_k || pi_old).
    pub estep_kl: Tensor,
    /// `[K]` mean Q_k of the samples (MPO) or `[C]` mean V_c (V-MPO).
    pub value_mean: Tensor,
    /// KL parts between target and online policy.
    pub policy_kl: Tensor,
    /// Phase timings; `target_update_ms` is filled in by `finish_members`.
    pub timings: PhaseTimings,
}

/// The wall clock of a step's phases, read as each one ends. Each reading waits for
/// the device first: its kernels run asynchronously, so an unsynchronized reading
/// would charge a phase's work to whichever phase next waits for a result.
#[derive(Debug)]
pub(crate) struct PhaseClock {
    device: Device,
    since: Instant,
    timings: PhaseTimings,
}

impl PhaseClock {
    /// A clock whose first phase starts now.
    pub(crate) fn start(device: Device) -> Self {
        Self {
            device,
            since: Instant::now(),
            timings: PhaseTimings::default(),
        }
    }

    /// Milliseconds since the last phase ended; the next phase starts now.
    fn lap(&mut self) -> f64 {
        let ms = ms_since(self.since, self.device);
        self.since = Instant::now();
        ms
    }

    /// Policy evaluation (the critics' targets and their update) has ended.
    pub(crate) fn policy_evaluation_done(&mut self) {
        self.timings.policy_evaluation_ms = self.lap();
    }

    /// The E-step (MO-V-MPO: step 1) has ended.
    pub(crate) fn e_step_done(&mut self) {
        self.timings.e_step_ms = self.lap();
    }

    /// The M-step (MO-V-MPO: step 2) and the dual updates have ended.
    pub(crate) fn m_step_done(&mut self) {
        self.timings.m_step_ms = self.lap();
    }

    /// The phases so far; the target update is `finish_members`'s to time.
    pub(crate) fn timings(&self) -> PhaseTimings {
        self.timings
    }
}

impl Learner {
    /// Rewards of the critic heads, with each member's map for member-first rewards.
    /// # Shapes
    /// `rewards [T, B, K_env] -> [T, B, C]` (one member), `[P, T, B, K_env] -> [P, T, B, C]`.
    pub(crate) fn critic_rewards(&self, rewards: &Tensor) -> Tensor {
        if rewards.dim() == 3 {
            return rewards.matmul(&self.critic_reward_weights);
        }
        let size = rewards.size();
        let weights = self.critic_reward_weights.reshape([size[0], size[3], -1]);
        rewards
            .reshape([size[0], -1, size[3]])
            .bmm(&weights)
            .reshape([size[0], size[1], size[2], -1])
    }

    /// One Adam step on the critics for `loss` (the sum of the members' losses),
    /// clipped as configured (each member's gradient by its own norm).
    pub(crate) fn update_critics(&mut self, loss: &Tensor) {
        self.critic_opt.zero_grad();
        loss.backward();
        if let Some(max) = self.settings.grad_clip_norm {
            self.critic_opt.clip_grad_norm_members(max, self.members);
        }
        self.critic_opt.step();
    }

    /// Policy fit under the decoupled trust region plus `temperature_loss`; one Adam
    /// step on the policy and one on the duals. Returns the KL parts (KL_mu, KL_Sigma)
    /// or (KL) between target and online policy before the update; with a
    /// per-dimension constraint each part is the mean over the D dimensions' KLs (the
    /// number each beta bounds).
    /// # Shapes
    /// Gaussian: `actions [.., M, N, D]`, `weights [.., M, N]`; categorical: `actions`
    /// unused, `weights [.., A, N]`; leading member axes `..` (each member's mean over
    /// its states by `states`). The loss is `-mean_N sum_M w log pi`, so weights that
    /// sum to 1 over the batch must come scaled by N. Returns `[P, parts]`.
    /// `per_point`: each state's grid point, when an ε-conditioned learner keeps one
    /// trust region per grid point (Gaussian policies).
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn fit_policy(
        &mut self,
        online: &PolicyOutput,
        target: &PolicyOutput,
        actions: &Tensor,
        weights: &Tensor,
        temperature_loss: &Tensor,
        states: StateMean<'_>,
        per_point: Option<&StatePreferences>,
    ) -> Tensor {
        // [.., parts, multipliers per part]
        let alpha = self.duals.alpha();
        let s = self.settings;
        let p = self.members.count();
        // One KL per member and part: per-dimension KLs averaged (what each beta bounds).
        let per_member = |kl: &Tensor| kl.reshape([p, -1]).mean_dim(-1, false, Kind::Float);
        let (policy_loss, alpha_loss, policy_kl) = match (online, target) {
            (PolicyOutput::Gaussian(online), PolicyOutput::Gaussian(target)) => {
                let (alpha_mean, alpha_cov) = (alpha.select(-2, 0), alpha.select(-2, 1));
                let region = TrustRegion {
                    alpha_mean: &alpha_mean,
                    alpha_cov: &alpha_cov,
                    beta_mean: s.beta_mean,
                    beta_cov: s.beta_cov,
                    constraint: s.kl_constraint,
                    per_point,
                };
                let out = gaussian_mstep_with(online, target, actions, weights, &region, states);
                let parts = [&out.kl_mean, &out.kl_cov].map(per_member);
                (out.policy_loss, out.alpha_loss, Tensor::stack(&parts, -1))
            }
            (PolicyOutput::Categorical(online), PolicyOutput::Categorical(target)) => {
                let alpha = alpha.reshape(online.size()[..online.dim() - 2].to_vec());
                let out = categorical_mstep_with(
                    online,
                    target,
                    weights,
                    &alpha,
                    s.beta_categorical,
                    states,
                );
                (
                    out.policy_loss,
                    out.alpha_loss,
                    per_member(&out.kl).unsqueeze(-1),
                )
            }
            _ => unreachable!("online and target policies have the same kind"),
        };
        self.policy_opt.zero_grad();
        self.duals.zero_grad();
        (policy_loss + alpha_loss + temperature_loss).backward();
        if let Some(max) = s.grad_clip_norm {
            self.policy_opt.clip_grad_norm_members(max, self.members);
        }
        self.policy_opt.step();
        self.duals.step();
        policy_kl
    }

    /// Counts the step, copies the targets when due, and reports every member's step:
    /// the measures are member-first (`[P, ..]`), and all members' statistics come to
    /// the host in one copy.
    pub(crate) fn finish_members(
        &mut self,
        measured: StepMeasures,
    ) -> Result<Vec<LearnerStats>, LearnerError> {
        let start = Instant::now();
        self.advance_targets()?;
        let target_update_ms = ms_since(start, self.device);
        let p = self.members.count();
        let alpha = self.duals.alpha();
        let alpha = alpha.reshape([p, alpha.size()[alpha.dim() - 2], -1]);
        let kept = match self.policy_step_kept.take() {
            Some(kept) => kept.reshape([p, 1]),
            None => Tensor::ones([p, 1], (Kind::Float, self.device)),
        };
        let columns = [
            measured.critic_loss.reshape([p, -1]),
            self.duals.temperature().reshape([p, -1]),
            measured.estep_kl.reshape([p, -1]),
            measured.value_mean.reshape([p, -1]),
            alpha.mean_dim(-1, false, Kind::Float),
            measured.policy_kl.reshape([p, -1]),
            kept,
        ];
        let widths: Vec<usize> = columns.iter().map(|c| c.size()[1] as usize).collect();
        let table = to_vec(&Tensor::cat(&columns, 1));
        let row_len: usize = widths.iter().sum();
        let timings = PhaseTimings {
            target_update_ms,
            ..measured.timings
        };
        Ok(table
            .chunks(row_len.max(1))
            .take(p as usize)
            .map(|row| {
                let mut parts = Vec::with_capacity(widths.len());
                let mut at = 0;
                for w in &widths {
                    parts.push(row[at..at + w].to_vec());
                    at += w;
                }
                let mut parts = parts.into_iter();
                let mut next = || parts.next().unwrap_or_default();
                LearnerStats {
                    step: self.step,
                    critic_loss: next(),
                    temperature: next(),
                    estep_kl: next(),
                    q_mean: next(),
                    alpha: next(),
                    policy_kl: next(),
                    policy_step_kept: next().first().copied().unwrap_or(1.0),
                    timings,
                }
            })
            .collect())
    }

    /// Counts the step and updates the target networks when due (C.1): a copy, or
    /// with `target_update_rate` < 1 a step of that size towards the online networks.
    pub(crate) fn advance_targets(&mut self) -> Result<(), LearnerError> {
        self.step += 1;
        if !self.step.is_multiple_of(self.settings.target_update_period) {
            return Ok(());
        }
        let rate = self.settings.target_update_rate;
        move_towards(&mut self.nets.target_policy_vs, &self.nets.policy_vs, rate)?;
        if let Critics::Q { target_vs, .. } = &mut self.nets.critics {
            move_towards(target_vs, &self.nets.critic_vs, rate)?;
        }
        Ok(())
    }
}

/// `target <- target + rate (online - target)` for every variable (a copy at rate 1,
/// bit for bit, as the paper's periodic update).
fn move_towards(
    target: &mut nn::VarStore,
    online: &nn::VarStore,
    rate: f64,
) -> Result<(), LearnerError> {
    if rate >= 1.0 {
        return Ok(target.copy(online)?);
    }
    let online = online.variables();
    tch::no_grad(|| {
        for (name, mut t) in target.variables() {
            let source = online.get(&name).ok_or_else(|| {
                tch::TchError::Torch(format!("target variable {name} has no online twin"))
            })?;
            let _ = t.lerp_(source, rate);
        }
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn store(value: f64) -> nn::VarStore {
        let vs = nn::VarStore::new(Device::Cpu);
        let _ = vs.root().var("w", &[3], nn::Init::Const(value));
        vs
    }

    fn value(vs: &nn::VarStore) -> f64 {
        vs.variables()["w"].mean(Kind::Float).double_value(&[])
    }

    #[test]
    fn targets_move_by_the_rate_and_a_rate_of_one_copies() {
        let online = store(1.0);
        let mut target = store(0.0);
        move_towards(&mut target, &online, 0.25).unwrap();
        assert!((value(&target) - 0.25).abs() < 1e-7);
        // Polyak averaging: after n steps the gap is (1 - rate)^n of the first.
        for _ in 0..9 {
            move_towards(&mut target, &online, 0.25).unwrap();
        }
        assert!((value(&target) - (1.0 - 0.75f64.powi(10))).abs() < 1e-6);
        move_towards(&mut target, &online, 1.0).unwrap();
        assert_eq!(value(&target), 1.0);
    }
}
