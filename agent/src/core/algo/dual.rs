//! Positive Lagrange multipliers: the temperatures eta_k of the E-step (eq. 34) and the
//! trust-region multipliers alpha of the M-step (eqs. 17-20).
//!
//! Each multiplier is `softplus(param) + 1e-8` (the temperatures optionally
//! `exp(param) + 1e-8`, `TemperatureParameterization::Log`), the parameter gets one Adam step per
//! learner step (its own optimizer, dual learning rate and second-moment decay, never
//! gradient-clipped) and is projected onto its floor *after* the update, as in Acme's
//! JAX learner: a clamp inside the loss would give a clamped dual zero gradient and it
//! could never recover (acme_mompo.md §1, §9.5). The floor is -18 (a multiplier of
//! ~1.5e-8, "positive" as C.3 and D.2.1 ask) unless a trust-region part has a lower
//! bound (`mpo.min_alpha_mean` etc.), whose parameter is then the floor.
//!
//! The trust region's multipliers come in `parts` groups (2 for a Gaussian policy:
//! alpha_mu and alpha_Sigma; 1 for a categorical one) of P each (1 when the summed KL is
//! bounded, D when each action dimension's KL is, see `mstep.rs`). They are stored
//! flat, part by part, so a summed Gaussian's parameter is `[2]` as it always was.
//!
//! A population of P >= 2 members stacks every parameter behind a member axis
//! (`[P, K]`, `[P, parts * P]`); one member keeps the unstacked shapes.

use super::adam::{Adam, AdamConfig};
use crate::core::learner_config::TemperatureParameterization;
use crate::core::nets::Members;
use tch::{Device, Kind, Tensor};

/// Added to softplus so a multiplier is never exactly 0.
pub const DUAL_OFFSET: f64 = 1e-8;
/// Floor applied to the raw parameters after each update.
pub const DUAL_PARAM_FLOOR: f64 = -18.0;

/// `softplus(param) + 1e-8`, differentiable in `param`.
pub fn positive(param: &Tensor) -> Tensor {
    param.softplus() + DUAL_OFFSET
}

/// The parameter whose `positive` is `value` (value > 1e-8).
pub fn inverse_positive(value: f64) -> f64 {
    let x = value - DUAL_OFFSET;
    // log(exp(x) - 1) written stably for large x.
    x + (-(-x).exp_m1()).ln()
}

/// `exp(param) + 1e-8`, differentiable in `param`.
pub fn positive_log(param: &Tensor) -> Tensor {
    param.exp() + DUAL_OFFSET
}

/// The parameter whose `positive_log` is `value` (value > 1e-8).
pub fn inverse_positive_log(value: f64) -> f64 {
    (value - DUAL_OFFSET).ln()
}

fn host(t: &Tensor) -> Vec<f32> {
    Vec::<f32>::try_from(&t.detach().to_device(Device::Cpu).to_kind(Kind::Float))
        .unwrap_or_default()
}

/// The parameter floor of a multiplier bounded below by `min` (0: none).
pub fn param_floor(min: f64) -> f64 {
    match min > positive_value(DUAL_PARAM_FLOOR) {
        true => inverse_positive(min),
        false => DUAL_PARAM_FLOOR,
    }
}

/// `positive` of a host value.
fn positive_value(param: f64) -> f64 {
    param.exp().ln_1p() + DUAL_OFFSET
}

/// One trust-region part's multipliers: their initial values (P of them) and lower bound.
#[derive(Debug, Clone, PartialEq)]
pub struct AlphaPart {
    /// Initial values, one per multiplier of the part (1, or D per dimension).
    pub init: Vec<f64>,
    /// Lower bound the part is projected onto after each step (0: the parameter floor).
    pub min: f64,
}

/// How the duals are optimized.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DualOptimizer {
    /// Adam learning rate.
    pub lr: f64,
    /// Adam second-moment decay.
    pub beta2: f64,
    /// How the temperatures are parameterized.
    pub temperature_kind: TemperatureParameterization,
}

/// All dual variables of one learner.
#[derive(Debug)]
pub struct Duals {
    /// Raw temperature parameters, `[K]`.
    pub temperature_param: Tensor,
    /// Raw trust-region parameters, `[parts * P]` part by part: (alpha_mu,
    /// alpha_Sigma) for Gaussian policies (P = 1 or D each), (alpha) for categorical ones.
    pub alpha_param: Tensor,
    /// Number of trust-region parts (2 Gaussian, 1 categorical).
    alpha_parts: i64,
    /// `[parts * P]` (stacked `[members, parts * P]`): each alpha parameter's floor.
    alpha_floor: Tensor,
    /// How `temperature_param` maps to eta.
    temperature_kind: TemperatureParameterization,
    pub(crate) optimizer: Adam,
}

impl Duals {
    /// Multipliers starting at the given (positive) values; `alphas` has one part per
    /// trust-region part, all of the same length P.
    pub fn new(
        temperatures: &[f64],
        alphas: &[AlphaPart],
        optimizer: DualOptimizer,
        device: Device,
    ) -> Self {
        Self::with_members(temperatures, alphas, optimizer, device, Members::ONE)
    }

    /// As `new`, for `members` members that all start at the given values.
    pub fn with_members(
        temperatures: &[f64],
        alphas: &[AlphaPart],
        optimizer: DualOptimizer,
        device: Device,
        members: Members,
    ) -> Self {
        let stack = |one: Tensor| match members.stacked() {
            true => one.unsqueeze(0).repeat([members.count(), 1]),
            false => one,
        };
        let make = |values: &[f64], inverse: fn(f64) -> f64| {
            let raw: Vec<f32> = values.iter().map(|&v| inverse(v) as f32).collect();
            stack(Tensor::from_slice(&raw).to_device(device)).set_requires_grad(true)
        };
        let temperature_param = make(
            temperatures,
            match optimizer.temperature_kind {
                TemperatureParameterization::Softplus => inverse_positive,
                TemperatureParameterization::Log => inverse_positive_log,
            },
        );
        let init: Vec<f64> = alphas.iter().flat_map(|a| a.init.iter().copied()).collect();
        // A part that starts under its bound starts on it.
        let floors: Vec<f32> = alphas
            .iter()
            .flat_map(|a| a.init.iter().map(|_| param_floor(a.min) as f32))
            .collect();
        let alpha_floor = stack(Tensor::from_slice(&floors).to_device(device));
        let alpha_param = make(&init, inverse_positive);
        tch::no_grad(|| {
            let _ = alpha_param.shallow_clone().clamp_min_tensor_(&alpha_floor);
        });
        let params = vec![
            ("temperature".to_string(), temperature_param.shallow_clone()),
            ("alpha".to_string(), alpha_param.shallow_clone()),
        ];
        // Adam's eps for the duals is PyTorch's default (Acme).
        let adam = AdamConfig {
            beta2: optimizer.beta2,
            ..AdamConfig::new(optimizer.lr, 1e-8)
        };
        Self {
            temperature_param,
            alpha_param,
            alpha_parts: alphas.len() as i64,
            alpha_floor,
            temperature_kind: optimizer.temperature_kind,
            optimizer: Adam::new(params, adam),
        }
    }

    /// eta_k, `[K]` (`[P, K]` stacked), differentiable.
    pub fn temperature(&self) -> Tensor {
        match self.temperature_kind {
            TemperatureParameterization::Softplus => positive(&self.temperature_param),
            TemperatureParameterization::Log => positive_log(&self.temperature_param),
        }
    }

    /// alpha values, `[parts, P]` (`[members, parts, P]` stacked), differentiable.
    pub fn alpha(&self) -> Tensor {
        let size = self.alpha_param.size();
        let shape = [&size[..size.len() - 1], &[self.alpha_parts, -1]].concat();
        positive(&self.alpha_param).reshape(shape.as_slice())
    }

    /// Clears the dual gradients (before the backward pass that fills them).
    pub fn zero_grad(&mut self) {
        self.optimizer.zero_grad();
    }

    /// One Adam step on the duals, then the projection onto their floors.
    pub fn step(&mut self) {
        self.optimizer.step();
        tch::no_grad(|| {
            let _ = self.temperature_param.clamp_min_(DUAL_PARAM_FLOOR);
            let _ = self.alpha_param.clamp_min_tensor_(&self.alpha_floor);
        });
    }

    /// Current values as host vectors: eta_k, and per trust-region part the mean of
    /// its P multipliers (the multiplier itself when P = 1).
    pub fn values(&self) -> (Vec<f32>, Vec<f32>) {
        let alpha_means = self.alpha().mean_dim(-1, false, Kind::Float);
        (host(&self.temperature()), host(&alpha_means))
    }

    /// Every multiplier, per trust-region part: `[parts][P]`.
    pub fn alpha_by_part(&self) -> Vec<Vec<f32>> {
        let alpha = self.alpha();
        (0..self.alpha_parts)
            .map(|part| host(&alpha.get(part)))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn optimizer(lr: f64, temperature_kind: TemperatureParameterization) -> DualOptimizer {
        DualOptimizer {
            lr,
            beta2: 0.999,
            temperature_kind,
        }
    }

    fn part(init: f64, min: f64) -> AlphaPart {
        AlphaPart {
            init: vec![init],
            min,
        }
    }

    #[test]
    fn log_temperatures_round_trip_and_step_relatively() {
        for v in [1e-6, 0.1, 1.0, 10.0, 1000.0] {
            let p = Tensor::from_slice(&[inverse_positive_log(v)]);
            assert!((positive_log(&p).double_value(&[0]) - v).abs() < 1e-6 * v.max(1.0));
        }
        // One Adam step moves the parameter by about lr, so eta by a factor of about
        // exp(lr) at any size: the same pull takes 1 -> e^0.1 and 100 -> 100 e^0.1.
        for start in [1.0, 100.0] {
            let mut duals = Duals::new(
                &[start],
                &[part(1.0, 0.0)],
                optimizer(0.1, TemperatureParameterization::Log),
                Device::Cpu,
            );
            duals.zero_grad();
            (-duals.temperature()).sum(Kind::Float).backward();
            duals.step();
            let ratio = duals.temperature().double_value(&[0]) / start;
            assert!((ratio - 0.1f64.exp()).abs() < 1e-3, "{start}: {ratio}");
        }
    }

    #[test]
    fn inverse_round_trips_and_floor_holds() {
        for v in [1e-6, 0.1, 1.0, 10.0, 1000.0] {
            let p = Tensor::from_slice(&[inverse_positive(v)]);
            assert!(
                (positive(&p).double_value(&[0]) - v).abs() < 1e-6 * v.max(1.0),
                "{v}"
            );
        }
        let mut duals = Duals::new(
            &[1e-7],
            &[part(1.0, 0.0), part(1.0, 0.0)],
            optimizer(10.0, TemperatureParameterization::Softplus),
            Device::Cpu,
        );
        duals.zero_grad();
        // A huge push towards 0 lands on the floor, not below.
        (duals.temperature() * 1e6).sum(Kind::Float).backward();
        duals.step();
        duals.zero_grad();
        (duals.temperature() * 1e6).sum(Kind::Float).backward();
        duals.step();
        assert!(duals.temperature_param.double_value(&[0]) >= DUAL_PARAM_FLOOR);
        assert!(duals.temperature().double_value(&[0]) > 0.0);
    }

    /// Pushes every alpha towards 0 for `steps` steps; returns the alphas of each part.
    fn pushed_down(duals: &mut Duals, steps: usize) -> Vec<Vec<f32>> {
        for _ in 0..steps {
            duals.zero_grad();
            duals.alpha().sum(Kind::Float).backward();
            duals.step();
        }
        duals.alpha_by_part()
    }

    #[test]
    fn each_part_is_projected_onto_its_lower_bound() {
        let mut duals = Duals::new(
            &[1.0],
            &[part(5.0, 2.0), part(0.5, 0.0)],
            optimizer(1.0, TemperatureParameterization::Softplus),
            Device::Cpu,
        );
        let alpha = pushed_down(&mut duals, 300);
        assert!((alpha[0][0] - 2.0).abs() < 1e-5, "{alpha:?}");
        // The other part has no bound: it falls on towards the parameter floor (Adam's
        // steps shrink with softplus' slope, so it gets there slowly).
        assert!(alpha[1][0] < 1e-3, "unbounded part: {alpha:?}");
        // A part that starts below its bound starts on it.
        let duals = Duals::new(
            &[1.0],
            &[part(0.1, 3.0)],
            optimizer(1.0, TemperatureParameterization::Softplus),
            Device::Cpu,
        );
        assert!((duals.alpha_by_part()[0][0] - 3.0).abs() < 1e-5);
        assert_eq!(param_floor(0.0), DUAL_PARAM_FLOOR);
    }

    /// Steps after one large violation (gradient `-spike` for `spike_steps` steps)
    /// until alpha is back under half its peak, pulled down by a usual gradient of 1e-3.
    fn steps_to_release(beta2: f64) -> usize {
        let mut duals = Duals::new(
            &[1.0],
            &[part(0.1, 0.0)],
            DualOptimizer {
                lr: 0.1,
                beta2,
                temperature_kind: TemperatureParameterization::Softplus,
            },
            Device::Cpu,
        );
        let pull = |duals: &mut Duals, gradient: f64| {
            duals.zero_grad();
            (duals.alpha() * gradient).sum(Kind::Float).backward();
            duals.step();
        };
        for _ in 0..100 {
            pull(&mut duals, -1.0);
        }
        let peak = duals.alpha_by_part()[0][0];
        (1..=20_000)
            .find(|_| {
                pull(&mut duals, 1e-3);
                duals.alpha_by_part()[0][0] < peak / 2.0
            })
            .unwrap_or(usize::MAX)
    }

    #[test]
    fn a_short_second_moment_forgets_a_spike() {
        // With beta2 = 0.999 the spike's squared gradient dominates Adam's denominator
        // for thousands of steps, so alpha stays near its peak (the frozen policy of
        // docs/stability.md); with 0.9 it falls at the usual pace.
        let long = steps_to_release(0.999);
        let short = steps_to_release(0.9);
        assert!(long > 2_000, "beta2 0.999: {long} steps");
        assert!(short < 200, "beta2 0.9: {short} steps");
    }
}
