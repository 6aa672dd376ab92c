//! A bound on a whole MO-V-MPO learner step (`vmpo.project_step_kl`). Eq. 25 bounds
//! KL(pi_old || pi) < beta through a Lagrange multiplier alpha that takes one
//! gradient step per update, so it bounds the KL only on average; a step of several
//! updates on one batch (`vmpo.epochs`, `vmpo.minibatches`) can end well past beta
//! (0.2-0.3 against beta_mu = 0.1 on mocap). After such a step the learner measures
//! the KL of each part (KL_mu and KL_Sigma of eqs. 18-20, or the categorical KL) at the
//! step's real states, and a member whose KL exceeds a beta gets its policy
//! parameters pulled back along the segment from the step's start to its end,
//! `theta(t) = theta_start + t (theta_end - theta_start)` (`projection::Displacement`,
//! which MPO's projection moves along from the target policy), as TRPO's line search does:
//! near t = 0 the KL grows as t^2, so each trial takes `t <- 0.9 t sqrt(1 / r)`
//! (r the largest ratio KL / beta, the factor kept in [0.1, 0.9]) until every part is
//! within its beta, and after `TRIALS` trials the step's start. The start is pi_old
//! itself when pi_old is renewed every learner step (`target_update_period = 1`, as
//! in the presets that reuse batches), so then every step ends within beta; with a
//! longer period the start was checked at the previous batch's states only. Adam's
//! moments are left as the updates made them.
//!
//! Shape legend: P members, R real states, D action dims, A actions.

use super::estep::StateMean;
use super::mstep::{KlConstraint, decoupled_kl};
use super::projection::Displacement;
use super::real_states::{RealStates, gather_states, real_rows};
use super::state::Learner;
use crate::core::nets::{GaussianParams, PolicyOutput};
use crate::core::random::{Purpose, StreamKey};
use std::collections::HashMap;
use tch::{Kind, Tensor};

/// Line-search trials before falling back to the step's start.
const TRIALS: usize = 8;

/// The policy's parameters by name, copied.
pub(super) type Parameters = HashMap<String, Tensor>;

/// A step's end, measured (and projected when configured).
#[derive(Debug)]
pub(super) struct StepEnd {
    /// `[P, parts]`: KL(pi_old || pi) at the step's end, reported as `fit_policy`
    /// reports it (per-dimension: the mean over D).
    pub kl: Tensor,
}

impl Learner {
    /// A copy of the online policy's parameters.
    pub(super) fn policy_parameters(&self) -> Parameters {
        self.nets
            .policy_vs
            .variables()
            .into_iter()
            .map(|(name, t)| (name, t.detach().copy()))
            .collect()
    }

    /// KL(pi_old || pi) at the states `obs [P, R, obs]`: the reported parts `[P,
    /// parts]` and the largest ratio KL / beta of each member `[P]`. In f64: KL_Sigma
    /// near beta_Sigma = 1e-5 is a difference of terms near 1/2, which f32 gets only
    /// to about 1e-3 relative, and the projection compares it with beta.
    fn step_kl(&self, obs: &Tensor, noise: Option<&Tensor>, real: &RealStates) -> (Tensor, Tensor) {
        let s = &self.settings;
        let mean = StateMean::Members(&real.weight);
        let wide = |g: GaussianParams| GaussianParams {
            mean: g.mean.to_kind(Kind::Double),
            std: g.std.to_kind(Kind::Double),
        };
        tch::no_grad(|| {
            let target = self.nets.target_policy.forward_members(obs, noise);
            match (self.nets.policy.forward_members(obs, noise), target) {
                (PolicyOutput::Gaussian(online), PolicyOutput::Gaussian(target)) => {
                    let kl = decoupled_kl(&wide(online), &wide(target));
                    let part = |kl: Tensor, beta: f64| {
                        let per_dim = mean.over_states(&kl);
                        let (reported, bounded) = match s.kl_constraint {
                            KlConstraint::Summed => {
                                let total = per_dim.sum_dim_intlist(-1, false, Kind::Double);
                                (total.shallow_clone(), total)
                            }
                            KlConstraint::PerDimension => (
                                per_dim.mean_dim(-1, false, Kind::Double),
                                per_dim.amax([-1i64].as_slice(), false),
                            ),
                        };
                        (reported, bounded / beta)
                    };
                    let (mean_kl, mean_ratio) = part(kl.mean, s.beta_mean);
                    let (cov_kl, cov_ratio) = part(kl.cov, s.beta_cov);
                    (
                        Tensor::stack(&[mean_kl, cov_kl], -1).to_kind(Kind::Float),
                        mean_ratio.maximum(&cov_ratio),
                    )
                }
                (PolicyOutput::Categorical(online), PolicyOutput::Categorical(target)) => {
                    let old = target.to_kind(Kind::Double).log_softmax(-1, Kind::Double);
                    let new = online.to_kind(Kind::Double).log_softmax(-1, Kind::Double);
                    let per_state =
                        (old.exp() * (&old - new)).sum_dim_intlist(-1, false, Kind::Double);
                    let kl = mean.over_state_rows(&per_state);
                    (
                        kl.unsqueeze(-1).to_kind(Kind::Float),
                        kl / s.beta_categorical,
                    )
                }
                _ => unreachable!("online and target policies have the same kind"),
            }
        })
    }

    /// Measures the step's end at the real states of `observations [P, N, obs]`
    /// (`valid [P, N]`) and, with `start` given, projects each member whose KL
    /// exceeds a beta back towards it (see module docs).
    pub(super) fn end_step(
        &mut self,
        observations: &Tensor,
        valid: &Tensor,
        start: Option<&Parameters>,
    ) -> StepEnd {
        let real = real_rows(&valid.gt(0.5));
        let obs = match &real.index {
            None => observations.shallow_clone(),
            Some(index) => gather_states(observations, index, 1),
        };
        let mut stream = StreamKey::new(self.cfg.seed, Purpose::LatentNoise, 1).at(self.step);
        let noise = self.nets.policy.latent_noise(obs.size()[1], &mut stream);
        let (mut kl, ratio) = self.step_kl(&obs, noise.as_ref(), &real);
        let mut ratio: Vec<f64> = Vec::try_from(&ratio.to_kind(Kind::Double)).expect("[P]");
        let mut kept = vec![1.0; ratio.len()];
        let Some(start) = start else {
            return StepEnd { kl };
        };
        if ratio.iter().all(|&r| r <= 1.0) {
            return StepEnd { kl };
        }
        let displacement = Displacement::of(&self.nets.policy_vs, start, self.members);
        for trial in 0..=TRIALS {
            let over: Vec<bool> = ratio.iter().map(|&r| r > 1.0).collect();
            if !over.contains(&true) {
                break;
            }
            for ((t, &r), &o) in kept.iter_mut().zip(&ratio).zip(&over) {
                if o {
                    *t = match trial {
                        TRIALS => 0.0,
                        _ => *t * (0.9 / r.sqrt()).clamp(0.1, 0.9),
                    };
                }
            }
            let scale = Tensor::from_slice(&kept).to_kind(Kind::Float);
            displacement.keep(&scale.to_device(self.device));
            let (now, now_ratio) = self.step_kl(&obs, noise.as_ref(), &real);
            let now_ratio: Vec<f64> = Vec::try_from(&now_ratio.to_kind(Kind::Double)).expect("[P]");
            // Members already within their betas keep their parameters and measures;
            // one back at its start stops there, whatever its KL.
            let moved: Vec<f32> = over.iter().map(|&o| if o { 1.0 } else { 0.0 }).collect();
            let moved = Tensor::from_slice(&moved)
                .to_device(self.device)
                .unsqueeze(-1);
            kl = &now * &moved + &kl * (1.0 - &moved);
            for (((r, n), &o), &t) in ratio.iter_mut().zip(now_ratio).zip(&over).zip(&kept) {
                if o {
                    *r = if t == 0.0 { 0.0 } else { n };
                }
            }
        }
        StepEnd { kl }
    }
}
