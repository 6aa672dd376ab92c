//! The optimizer half of a learner step, shared by both algorithm families: the
//! critic's Adam step, the policy fit under the decoupled trust region (the M-step of
//! eqs. 16-20 for MO-MPO, step 2 of eq. 25 for MO-V-MPO; `mstep.rs` has the losses)
//! with one Adam step on the policy and one on the duals, and the target-network
//! schedule (C.1) that ends every step.
//!
//! Shape legend: N states, M samples (or A actions), D action dims, K objectives,
//! C learned critics.

use super::mstep::{TrustRegion, categorical_mstep, gaussian_mstep};
use super::state::{Critics, Learner, LearnerError, LearnerStats, PhaseTimings, ms_since, to_vec};
use crate::nets::PolicyOutput;
use std::time::Instant;
use tch::{Kind, Tensor};

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
    /// Phase timings; `target_update_ms` is filled in by `finish_step`.
    pub timings: PhaseTimings,
}

impl Learner {
    /// Rewards of the critic heads. # Shapes `rewards [T, B, K_env] -> [T, B, C]`.
    pub(crate) fn critic_rewards(&self, rewards: &Tensor) -> Tensor {
        rewards.matmul(&self.critic_reward_weights)
    }

    /// One Adam step on the critics for `loss`, clipped as configured.
    pub(crate) fn update_critics(&mut self, loss: &Tensor) {
        self.critic_opt.zero_grad();
        loss.backward();
        if let Some(max) = self.settings.grad_clip_norm {
            self.critic_opt.clip_grad_norm(max);
        }
        self.critic_opt.step();
    }

    /// Policy fit under the decoupled trust region plus `temperature_loss`; one Adam
    /// step on the policy and one on the duals. Returns the KL parts (KL_mu, KL_Sigma)
    /// or (KL) between target and online policy before the update; with a
    /// per-dimension constraint each part is the mean over the D dimensions' KLs (the
    /// number each beta bounds).
    /// # Shapes
    /// Gaussian: `actions [M, N, D]`, `weights [M, N]`; categorical: `actions`
    /// unused, `weights [A, N]`. The loss is `-mean_N sum_M w log pi`, so weights that
    /// sum to 1 over the batch must come scaled by N.
    pub(crate) fn fit_policy(
        &mut self,
        online: &PolicyOutput,
        target: &PolicyOutput,
        actions: &Tensor,
        weights: &Tensor,
        temperature_loss: &Tensor,
    ) -> Tensor {
        // [parts, P]
        let alpha = self.duals.alpha();
        let s = self.settings;
        let (policy_loss, alpha_loss, policy_kl) = match (online, target) {
            (PolicyOutput::Gaussian(online), PolicyOutput::Gaussian(target)) => {
                let (alpha_mean, alpha_cov) = (alpha.get(0), alpha.get(1));
                let region = TrustRegion {
                    alpha_mean: &alpha_mean,
                    alpha_cov: &alpha_cov,
                    beta_mean: s.beta_mean,
                    beta_cov: s.beta_cov,
                    constraint: s.kl_constraint,
                };
                let out = gaussian_mstep(online, target, actions, weights, &region);
                let parts = [&out.kl_mean, &out.kl_cov].map(|kl| kl.mean(Kind::Float));
                (out.policy_loss, out.alpha_loss, Tensor::stack(&parts, 0))
            }
            (PolicyOutput::Categorical(online), PolicyOutput::Categorical(target)) => {
                let alpha = alpha.reshape([-1]).get(0);
                let out = categorical_mstep(online, target, weights, &alpha, s.beta_categorical);
                (out.policy_loss, out.alpha_loss, out.kl.unsqueeze(0))
            }
            _ => unreachable!("online and target policies have the same kind"),
        };
        self.policy_opt.zero_grad();
        self.duals.zero_grad();
        (policy_loss + alpha_loss + temperature_loss).backward();
        if let Some(max) = s.grad_clip_norm {
            self.policy_opt.clip_grad_norm(max);
        }
        self.policy_opt.step();
        self.duals.step();
        policy_kl
    }

    /// Counts the step, copies the targets when due, and reports the step.
    pub(crate) fn finish_step(
        &mut self,
        measured: StepMeasures,
    ) -> Result<LearnerStats, LearnerError> {
        let start = Instant::now();
        self.advance_targets()?;
        let target_update_ms = ms_since(start, self.device);
        let (temperature, alpha) = self.duals.values();
        Ok(LearnerStats {
            step: self.step,
            critic_loss: to_vec(&measured.critic_loss),
            temperature,
            estep_kl: to_vec(&measured.estep_kl),
            q_mean: to_vec(&measured.value_mean),
            alpha,
            policy_kl: to_vec(&measured.policy_kl),
            timings: PhaseTimings {
                target_update_ms,
                ..measured.timings
            },
        })
    }

    /// Counts the step and copies the target networks when due (C.1).
    pub(crate) fn advance_targets(&mut self) -> Result<(), LearnerError> {
        self.step += 1;
        if self.step.is_multiple_of(self.settings.target_update_period) {
            self.target_policy_vs.copy(&self.policy_vs)?;
            if let Critics::Q { target_vs, .. } = &mut self.critics {
                target_vs.copy(&self.critic_vs)?;
            }
        }
        Ok(())
    }
}
