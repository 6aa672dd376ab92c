//! Positive Lagrange multipliers: the temperatures eta_k of the E-step (eq. 34) and the
//! trust-region multipliers alpha of the M-step (eqs. 17-20).
//!
//! Each multiplier is `softplus(param) + 1e-8` (the temperatures optionally
//! `exp(param) + 1e-8`, `TemperatureParameterization::Log`), the parameter gets one Adam step per
//! learner step (its own optimizer, dual learning rate, never gradient-clipped) and is
//! floored at -18 *after* the update (eta >= ~2.5e-8), as in Acme's JAX learner: a
//! clamp inside the loss would give a clamped dual zero gradient and it could never
//! recover (acme_mompo.md §1, §9.5).
//!
//! The trust region's multipliers come in `parts` groups (2 for a Gaussian policy:
//! alpha_mu and alpha_Sigma; 1 for a categorical one) of P each (1 when the summed KL is
//! bounded, D when each action dimension's KL is, see `mstep.rs`). They are stored
//! flat, part by part, so a summed Gaussian's parameter is `[2]` as it always was.
//!
//! A population of P >= 2 members stacks every parameter behind a member axis
//! (`[P, K]`, `[P, parts * P]`); one member keeps the unstacked shapes.

use super::adam::{Adam, AdamConfig};
use crate::config::TemperatureParameterization;
use crate::nets::Members;
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
    /// How `temperature_param` maps to eta.
    temperature_kind: TemperatureParameterization,
    pub(crate) optimizer: Adam,
}

impl Duals {
    /// Multipliers starting at the given (positive) values; `alphas` has one slice per
    /// trust-region part, all of the same length P.
    pub fn new(
        temperatures: &[f64],
        alphas: &[&[f64]],
        lr: f64,
        temperature_kind: TemperatureParameterization,
        device: Device,
    ) -> Self {
        Self::with_members(
            temperatures,
            alphas,
            lr,
            temperature_kind,
            device,
            Members::ONE,
        )
    }

    /// As `new`, for `members` members that all start at the given values.
    pub fn with_members(
        temperatures: &[f64],
        alphas: &[&[f64]],
        lr: f64,
        temperature_kind: TemperatureParameterization,
        device: Device,
        members: Members,
    ) -> Self {
        let make = |values: &[f64], inverse: fn(f64) -> f64| {
            let raw: Vec<f32> = values.iter().map(|&v| inverse(v) as f32).collect();
            let one = Tensor::from_slice(&raw).to_device(device);
            let stacked = match members.stacked() {
                true => one.unsqueeze(0).repeat([members.count(), 1]),
                false => one,
            };
            stacked.set_requires_grad(true)
        };
        let temperature_param = make(
            temperatures,
            match temperature_kind {
                TemperatureParameterization::Softplus => inverse_positive,
                TemperatureParameterization::Log => inverse_positive_log,
            },
        );
        let alpha_param = make(&alphas.concat(), inverse_positive);
        let params = vec![
            ("temperature".to_string(), temperature_param.shallow_clone()),
            ("alpha".to_string(), alpha_param.shallow_clone()),
        ];
        // Adam's eps for the duals is PyTorch's default; only lr is configured (Acme).
        let optimizer = Adam::new(params, AdamConfig::new(lr, 1e-8));
        Self {
            temperature_param,
            alpha_param,
            alpha_parts: alphas.len() as i64,
            temperature_kind,
            optimizer,
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

    /// One Adam step on the duals, then the floor.
    pub fn step(&mut self) {
        self.optimizer.step();
        tch::no_grad(|| {
            let _ = self.temperature_param.clamp_min_(DUAL_PARAM_FLOOR);
            let _ = self.alpha_param.clamp_min_(DUAL_PARAM_FLOOR);
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
                &[&[1.0]],
                0.1,
                TemperatureParameterization::Log,
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
            &[&[1.0], &[1.0]],
            10.0,
            TemperatureParameterization::Softplus,
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
}
