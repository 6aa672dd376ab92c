//! What one learner step reports (host values, for logs and progress displays).
//!
//! Shape legend: K objectives, C learned critics.

use serde::Serialize;

/// Wall-clock milliseconds per phase of one step.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct PhaseTimings {
    /// Sampling, target critic on all samples, Retrace, critic update.
    pub policy_evaluation_ms: f64,
    /// Weights and temperature losses.
    pub e_step_ms: f64,
    /// Policy forward, M-step losses, backward, policy and dual updates.
    pub m_step_ms: f64,
    /// Target network copy (when due) and bookkeeping.
    pub target_update_ms: f64,
}

/// What one learner step measured (host values, for logging).
#[derive(Debug, Clone, PartialEq)]
pub struct LearnerStats {
    /// Learner steps done, including this one.
    pub step: u64,
    /// Per critic head: 0.5 * mean squared Retrace error before the update.
    pub critic_loss: Vec<f32>,
    /// Per objective: eta_k after the update.
    pub temperature: Vec<f32>,
    /// Per objective: realised KL(q_k || pi_old).
    pub estep_kl: Vec<f32>,
    /// Per objective: mean Q_k over the sampled actions (MO-MPO); per critic head:
    /// mean V_c over the real steps (MO-V-MPO).
    pub q_mean: Vec<f32>,
    /// (alpha_mu, alpha_Sigma) or (alpha) after the update. With a per-dimension KL
    /// constraint, each is the mean of its D multipliers (`Learner::alpha_by_part`
    /// has them all).
    pub alpha: Vec<f32>,
    /// (KL_mu, KL_Sigma) or (KL) between the target and online policy before the
    /// update (a V-MPO step of several updates: at the step's end, after
    /// `vmpo.project_step_kl`), averaged over states. Summed constraint: the KL of
    /// the whole Gaussian (compare with beta); per-dimension constraint: the mean
    /// over the D dimensions of each dimension's KL (also compared with beta; times D
    /// it is the summed KL).
    pub policy_kl: Vec<f32>,
    /// The fraction of its M-step the policy kept after the trust region's projection
    /// (`mpo.max_kl_ratio`): 1 when the step stayed within (or no projection runs),
    /// 0 when it was undone.
    pub policy_step_kept: f32,
    /// Phase timings.
    pub timings: PhaseTimings,
}
