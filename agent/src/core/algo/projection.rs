//! The trust region's projection (`mpo.max_kl_ratio`): after the M-step's Adam step
//! (eqs. 16-20), a member whose policy has moved further from the target policy than
//! `max_kl_ratio` times its bound (either part of the decoupled Gaussian KL against
//! beta_mu / beta_Sigma, or the categorical KL against its beta) is moved back towards
//! the target policy along its displacement in parameter space until the KL on the
//! step's states is within the bound (`project`).
//!
//! Why: the paper keeps KL(pi_old || pi) < beta by Lagrangian relaxation (C.3), one
//! gradient step on the policy and one on alpha per learner step. That holds the
//! bound on average, not at every step: while the KL stays under beta, alpha decays
//! towards 0, and then one target period of Adam steps can move the policy by a KL
//! hundreds of times beta (measured on pendulum, docs/stability.md) before alpha has
//! grown back, which undoes a solved policy; the spike then drives alpha so high that
//! the policy is frozen for thousands of steps. The projection makes the bound hold
//! within the factor at the end of every step, as a projected gradient method keeps
//! its iterate feasible; the multipliers still set how the step trades improvement
//! against the KL inside the region.
//!
//! With a state-dependent Gaussian (the paper's) the mean and the covariance share
//! the torso, so one line search along all parameters serves both parts, and a step
//! whose covariance part is past its bound loses its mean's move too. With a
//! state-independent standard deviation (`network.policy_std`) the covariance's KL
//! depends on `std_raw` alone and the mean's on the other parameters, so each part is
//! projected along its own parameters against its own bound (`project_parts`).
//!
//! Shape legend: P members, N states, D action dims, A discrete actions.

use super::estep::StateMean;
use super::mstep::{KlConstraint, trust_region_kl};
use crate::core::nets::{GaussianParams, Members, PolicyOutput, STD_VARIABLE};
use std::collections::HashMap;
use tch::{Kind, Tensor, nn};

/// Halvings after the first shortening before a member is put at its target.
pub const HALVINGS: usize = 10;

/// The bounds a projection holds the policy to.
#[derive(Debug, Clone, Copy)]
pub struct Bounds {
    /// beta_mu.
    pub beta_mean: f64,
    /// beta_Sigma.
    pub beta_cov: f64,
    /// The categorical policy's beta.
    pub beta_categorical: f64,
    /// Summed or per-dimension Gaussian KL.
    pub constraint: KlConstraint,
}

/// A Gaussian policy's KL over its bound per part, `[P]` each (per dimension: the
/// largest over the dimensions).
pub struct PartRatios {
    /// KL_mu / beta_mu.
    pub mean: Tensor,
    /// KL_Sigma / beta_Sigma.
    pub cov: Tensor,
}

/// Each part's ratio of a Gaussian policy.
pub fn gaussian_ratios(
    online: &GaussianParams,
    target: &GaussianParams,
    bounds: &Bounds,
    states: StateMean<'_>,
) -> PartRatios {
    let kl = trust_region_kl(online, &target.detach(), bounds.constraint, states);
    let p = kl.mean.size()[0];
    let over = |kl: &Tensor, beta: f64| (kl / beta).reshape([p, -1]).amax(&[1i64][..], false);
    PartRatios {
        mean: over(&kl.mean, bounds.beta_mean),
        cov: over(&kl.cov, bounds.beta_cov),
    }
}

/// Each member's KL over its bound, `[P]`: the largest of its parts (and, per
/// dimension, of its dimensions).
pub fn kl_ratio(
    online: &PolicyOutput,
    target: &PolicyOutput,
    bounds: &Bounds,
    states: StateMean<'_>,
) -> Tensor {
    match (online, target) {
        (PolicyOutput::Gaussian(online), PolicyOutput::Gaussian(target)) => {
            let parts = gaussian_ratios(online, target, bounds, states);
            parts.mean.maximum(&parts.cov)
        }
        (PolicyOutput::Categorical(online), PolicyOutput::Categorical(target)) => {
            let log_online = online.log_softmax(-1, Kind::Float);
            let log_target = target.detach().log_softmax(-1, Kind::Float);
            let kl = (log_target.exp() * (&log_target - &log_online)).sum_dim_intlist(
                -1,
                false,
                Kind::Float,
            );
            states.over_state_rows(&kl) / bounds.beta_categorical
        }
        _ => unreachable!("online and target policies have the same kind"),
    }
}

/// The policy's displacement from a start (its target here, the step's start in
/// `vmpo_trust`), shortened member by member: the one line search both trust
/// regions move along.
pub(super) struct Displacement<'a> {
    online: &'a nn::VarStore,
    /// (name, start value, online - start) per variable.
    parts: Vec<(String, Tensor, Tensor)>,
    members: Members,
}

impl<'a> Displacement<'a> {
    /// From `start` (the policy's variables by name) to `online`'s current values.
    pub(super) fn of(
        online: &'a nn::VarStore,
        start: &HashMap<String, Tensor>,
        members: Members,
    ) -> Self {
        Self::of_selected(online, start, members, Select::All)
    }

    /// As `of`, along the variables `select` takes only.
    fn of_selected(
        online: &'a nn::VarStore,
        start: &HashMap<String, Tensor>,
        members: Members,
        select: Select,
    ) -> Self {
        let parts = online
            .variables()
            .into_iter()
            .filter(|(name, _)| select.takes(name))
            .map(|(name, now)| {
                let at = start[&name].detach();
                let away = (&now - &at).detach();
                (name, at, away)
            })
            .collect();
        Self {
            online,
            parts,
            members,
        }
    }

    /// Puts each member's policy at `start + scale_p * (online - start)`, `scale [P]`
    /// (float, on the policy's device).
    pub(super) fn keep(&self, scale: &Tensor) {
        let now = self.online.variables();
        tch::no_grad(|| {
            for (name, at, away) in &self.parts {
                let mut t = now[name].shallow_clone();
                let s = match self.members.stacked() {
                    true => {
                        let shape: Vec<i64> = std::iter::once(-1)
                            .chain(std::iter::repeat_n(1, t.dim() - 1))
                            .collect();
                        scale.reshape(shape.as_slice())
                    }
                    false => scale.reshape([0i64; 0].as_slice()),
                };
                t.copy_(&(at + away * s));
            }
        });
    }
}

/// Which of the policy's variables a line search moves.
#[derive(Debug, Clone, Copy)]
enum Select {
    /// Every variable.
    All,
    /// The state-independent standard deviation only (`nets::STD_VARIABLE`).
    Std,
    /// Every variable but the standard deviation.
    NotStd,
}

impl Select {
    fn takes(self, name: &str) -> bool {
        let std = name.rsplit('.').next() == Some(STD_VARIABLE);
        match self {
            Select::All => true,
            Select::Std => std,
            Select::NotStd => !std,
        }
    }
}

/// Whether any element of a boolean tensor is set.
fn any(t: &Tensor) -> bool {
    t.any().to_kind(Kind::Int64).int64_value(&[]) != 0
}

/// Moves each member whose `ratio_of` (the members' KL ratios at the current
/// parameters, `[P]`) exceeds `max_ratio` back towards its target policy: first to
/// where the KL would be 0.9 of the bound if it grew as the square of the
/// displacement (as the mean part does), then halving that until the ratio is within;
/// after [`HALVINGS`] halvings the member is put at its target (KL 0). Returns the
/// fraction of its displacement each member kept, `[P]` (1: untouched).
///
/// The displacement, not only the last step, is shortened: the bound is on the KL
/// from the target policy, which a batch of states the last step never saw can show
/// to be past it, and only moving towards the target brings it back.
pub fn project(
    online: &nn::VarStore,
    target: &nn::VarStore,
    members: Members,
    max_ratio: f64,
    ratio_of: impl FnMut() -> Tensor,
) -> Tensor {
    project_selected(online, target, members, max_ratio, Select::All, ratio_of)
}

/// [`project`] for a policy with a state-independent standard deviation: the
/// covariance part along `std_raw` against `ratios().cov`, then the mean part along
/// the other variables against `ratios().mean`. Returns the smaller fraction each
/// member kept of the two, `[P]`.
pub fn project_parts(
    online: &nn::VarStore,
    target: &nn::VarStore,
    members: Members,
    max_ratio: f64,
    mut ratios: impl FnMut() -> PartRatios,
) -> Tensor {
    let cov = project_selected(online, target, members, max_ratio, Select::Std, || {
        ratios().cov
    });
    let mean = project_selected(online, target, members, max_ratio, Select::NotStd, || {
        ratios().mean
    });
    cov.minimum(&mean)
}

fn project_selected(
    online: &nn::VarStore,
    target: &nn::VarStore,
    members: Members,
    max_ratio: f64,
    select: Select,
    mut ratio_of: impl FnMut() -> Tensor,
) -> Tensor {
    let ratio = tch::no_grad(&mut ratio_of);
    let mut outside = ratio.gt(max_ratio);
    let ones = ratio.ones_like().to_kind(Kind::Float);
    if !any(&outside) {
        return ones;
    }
    let displacement = Displacement::of_selected(online, &target.variables(), members, select);
    let first = (ratio.to_kind(Kind::Float).reciprocal() * (0.81 * max_ratio))
        .sqrt()
        .clamp_max(1.0);
    let mut scale = first.where_self(&outside, &ones);
    for halving in 0..=HALVINGS {
        displacement.keep(&scale);
        outside = tch::no_grad(&mut ratio_of).gt(max_ratio);
        if !any(&outside) {
            break;
        }
        let factor = match halving == HALVINGS {
            true => 0.0, // still outside: at the target
            false => 0.5,
        };
        scale = (&scale * factor).where_self(&outside, &scale);
        if halving == HALVINGS {
            displacement.keep(&scale);
        }
    }
    scale
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::Device;

    /// A store with one trainable `[members, 1]` parameter at `values`.
    fn store(values: &[f32]) -> nn::VarStore {
        let vs = nn::VarStore::new(Device::Cpu);
        let _ = vs
            .root()
            .var("w", &[values.len() as i64, 1], nn::Init::Const(0.0));
        set(&vs, values);
        vs
    }

    fn w(vs: &nn::VarStore) -> Vec<f32> {
        Vec::<f32>::try_from(&vs.variables()["w"].flatten(0, -1)).unwrap()
    }

    fn set(vs: &nn::VarStore, values: &[f32]) {
        tch::no_grad(|| {
            let mut t = vs.variables()["w"].shallow_clone();
            t.copy_(&Tensor::from_slice(values).reshape([-1, 1]));
        });
    }

    #[test]
    fn each_member_is_shortened_to_within_the_bound_or_put_at_its_target() {
        let target = store(&[0.0, 0.0, 0.0]);
        // Members displaced to 1, 0.1 and 1; member 2's bound cannot be met away
        // from its target.
        let online = store(&[1.0, 0.1, 1.0]);
        let beta = 0.01;
        let ratio = || {
            let w = online.variables()["w"].flatten(0, -1);
            let never =
                Tensor::from_slice(&[0.0f32, 0.0, 1e3]) * w.abs().gt(0.0).to_kind(Kind::Float);
            w.square() / beta + never
        };
        let kept = project(&online, &target, Members::new(3).unwrap(), 2.0, ratio);
        // Member 0: ratio 100 at w = 1, quadratic in w, so the first shortening to
        // sqrt(0.81 * 2 / 100) = 0.127 puts it at 0.9 of the bound, within.
        let kept = Vec::<f32>::try_from(&kept).unwrap();
        assert!((kept[0] - 0.1273).abs() < 1e-3, "{kept:?}");
        assert_eq!(kept[1..], [1.0, 0.0]);
        let at = w(&online);
        assert!(
            (at[0] - kept[0]).abs() < 1e-6 && at[1..] == [0.1, 0.0],
            "{at:?}"
        );
    }

    #[test]
    fn a_ratio_that_grows_slower_than_the_square_is_halved_into_the_bound() {
        let target = store(&[0.0]);
        let online = store(&[1.0]);
        // Linear in the displacement: 10 at w = 1. The first shortening (to
        // sqrt(0.81 * 2 / 10) = 0.402) leaves 4.02, two halvings 1.006 <= 2.
        let ratio = || online.variables()["w"].abs().flatten(0, -1) * 10.0;
        let kept = project(&online, &target, Members::ONE, 2.0, ratio);
        let kept = kept.double_value(&[0]);
        assert!((kept - 0.4025 / 4.0).abs() < 1e-3, "{kept}");
    }

    #[test]
    fn each_part_is_shortened_along_its_own_variables() {
        // "w" stands for the mean's parameters and "std_raw" for a state-independent
        // std's; ratio mean = w^2 / 0.01, cov = std_raw^2 / 0.01, bound 2 each.
        let two = |w: f32, std: f32| {
            let vs = nn::VarStore::new(Device::Cpu);
            let root = vs.root();
            let _ = root.var("w", &[1], nn::Init::Const(f64::from(w)));
            let _ = root.var(STD_VARIABLE, &[1], nn::Init::Const(f64::from(std)));
            vs
        };
        let value = |vs: &nn::VarStore, name: &str| vs.variables()[name].double_value(&[0]);
        let target = two(0.0, 0.0);
        // The mean within (ratio 1), the std past (ratio 100).
        let online = two(0.1, 1.0);
        let ratios = || PartRatios {
            mean: online.variables()["w"].square() / 0.01,
            cov: online.variables()[STD_VARIABLE].square() / 0.01,
        };
        let kept = project_parts(&online, &target, Members::ONE, 2.0, ratios);
        assert!(
            (value(&online, "w") - 0.1).abs() < 1e-7,
            "the mean's move is kept"
        );
        let std = value(&online, STD_VARIABLE);
        assert!(
            (std - 0.1273).abs() < 1e-3,
            "the std's move is shortened: {std}"
        );
        assert!((kept.double_value(&[0]) - 0.1273).abs() < 1e-3, "{kept:?}");
        // The whole-policy projection shortens both.
        let online = two(0.1, 1.0);
        let whole = || {
            let v = online.variables();
            (v["w"].square() / 0.01).maximum(&(v[STD_VARIABLE].square() / 0.01))
        };
        let kept = project(&online, &target, Members::ONE, 2.0, whole);
        assert!((kept.double_value(&[0]) - 0.1273).abs() < 1e-3, "{kept:?}");
        assert!(value(&online, "w") < 0.013, "{}", value(&online, "w"));
    }

    #[test]
    fn a_policy_within_the_bound_is_left_alone() {
        let target = store(&[0.5]);
        let online = store(&[0.6]);
        let kept = project(&online, &target, Members::ONE, 2.0, || {
            Tensor::from_slice(&[1.5f32])
        });
        assert_eq!(Vec::<f32>::try_from(&kept).unwrap(), vec![1.0]);
        assert_eq!(w(&online), vec![0.6]);
    }

    #[test]
    fn the_ratio_is_the_largest_part_over_its_bound() {
        let target = GaussianParams {
            mean: Tensor::zeros([1, 4, 2], (Kind::Float, Device::Cpu)),
            std: Tensor::ones([1, 4, 2], (Kind::Float, Device::Cpu)),
        };
        let online = GaussianParams {
            mean: target.mean.shallow_clone() + 0.1,
            std: target.std.shallow_clone(),
        };
        let bounds = Bounds {
            beta_mean: 1e-3,
            beta_cov: 1e-5,
            beta_categorical: 1e-3,
            constraint: KlConstraint::Summed,
        };
        let ratio = kl_ratio(
            &PolicyOutput::Gaussian(online),
            &PolicyOutput::Gaussian(target),
            &bounds,
            StateMean::Uniform,
        );
        // KL_mu = 2 dims x 0.1^2 / 2 = 0.01 = 10 beta_mu; KL_Sigma = 0.
        assert!((ratio.double_value(&[0]) - 10.0).abs() < 1e-4, "{ratio:?}");
    }
}
