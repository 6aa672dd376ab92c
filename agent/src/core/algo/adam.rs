//! Adam (Kingma & Ba 2015) over named tensors, written out so its state (moments and
//! step count) can be checkpointed; tch's `nn::Optimizer` does not expose its state.
//! The update is PyTorch's `torch.optim.Adam` (no weight decay, no amsgrad):
//! `m = b1 m + (1-b1) g`, `v = b2 v + (1-b2) g^2`,
//! `p -= lr / (1 - b1^t) * m / (sqrt(v) / sqrt(1 - b2^t) + eps)`.

use crate::core::nets::Members;
use std::collections::HashMap;
use tch::{Kind, Tensor, nn};

/// Adam hyperparameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AdamConfig {
    /// Learning rate.
    pub lr: f64,
    /// First-moment decay (0.9).
    pub beta1: f64,
    /// Second-moment decay (0.999).
    pub beta2: f64,
    /// Denominator epsilon (Table 2: 1e-3; humanoid 1e-8).
    pub eps: f64,
}

impl AdamConfig {
    /// Betas (0.9, 0.999) with the given lr and eps.
    pub fn new(lr: f64, eps: f64) -> Self {
        Self {
            lr,
            beta1: 0.9,
            beta2: 0.999,
            eps,
        }
    }
}

/// A state tensor missing from, or of the wrong shape in, a loaded optimizer state.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("optimizer state tensor {name}: {problem}")]
pub struct AdamStateError {
    /// Name of the tensor.
    pub name: String,
    /// What was wrong.
    pub problem: String,
}

/// Adam over a fixed, named list of leaf tensors.
#[derive(Debug)]
pub struct Adam {
    cfg: AdamConfig,
    params: Vec<(String, Tensor)>,
    exp_avg: Vec<Tensor>,
    exp_avg_sq: Vec<Tensor>,
    step: i64,
}

impl Adam {
    /// Optimises `params` (leaf tensors requiring grad).
    pub fn new(params: Vec<(String, Tensor)>, cfg: AdamConfig) -> Self {
        let exp_avg = params.iter().map(|(_, p)| p.zeros_like()).collect();
        let exp_avg_sq = params.iter().map(|(_, p)| p.zeros_like()).collect();
        Self {
            cfg,
            params,
            exp_avg,
            exp_avg_sq,
            step: 0,
        }
    }

    /// Optimises every trainable variable of `vs`, in name order.
    pub fn for_var_store(vs: &nn::VarStore, cfg: AdamConfig) -> Self {
        let mut params: Vec<(String, Tensor)> = vs
            .variables()
            .into_iter()
            .filter(|(_, t)| t.requires_grad())
            .collect();
        params.sort_by(|a, b| a.0.cmp(&b.0));
        Self::new(params, cfg)
    }

    /// Number of updates applied so far.
    pub fn step_count(&self) -> i64 {
        self.step
    }

    /// Zeroes the gradients of all parameters.
    pub fn zero_grad(&mut self) {
        for (_, p) in &mut self.params {
            p.zero_grad();
        }
    }

    /// The parameters' gradients that are defined (a parameter no loss reached has none).
    fn gradients(&self) -> Vec<Tensor> {
        self.params
            .iter()
            .map(|(_, p)| p.grad())
            .filter(Tensor::defined)
            .collect()
    }

    /// Scales gradients so their global L2 norm is at most `max`; returns the norm before.
    pub fn clip_grad_norm(&self, max: f64) -> f64 {
        tch::no_grad(|| {
            let grads = self.gradients();
            if grads.is_empty() {
                return 0.0;
            }
            let norms: Vec<Tensor> = grads.iter().map(|g| g.square().sum(Kind::Float)).collect();
            let total = Tensor::stack(&norms, 0)
                .sum(Kind::Float)
                .sqrt()
                .double_value(&[]);
            if total > max {
                for mut g in grads {
                    let _ = g.g_mul_scalar_(max / (total + 1e-6));
                }
            }
            total
        })
    }

    /// `clip_grad_norm` for `members` stacked members: each member's gradients (its
    /// slices of every parameter) are scaled by their own global norm, without a host
    /// read. One member is `clip_grad_norm` itself.
    pub fn clip_grad_norm_members(&self, max: f64, members: Members) {
        if !members.stacked() {
            self.clip_grad_norm(max);
            return;
        }
        tch::no_grad(|| {
            let grads = self.gradients();
            let Some(first) = grads.first() else {
                return;
            };
            let mut squares = first
                .zeros_like()
                .flatten(1, -1)
                .narrow(1, 0, 1)
                .squeeze_dim(1);
            for g in &grads {
                squares += g
                    .square()
                    .flatten(1, -1)
                    .sum_dim_intlist(1, false, Kind::Float);
            }
            // min(1, max / (norm + 1e-6)): members under the bound keep their gradient.
            let scale = (squares.sqrt() + 1e-6)
                .reciprocal()
                .g_mul_scalar(max)
                .clamp_max(1.0);
            for mut g in grads {
                let shape: Vec<i64> = std::iter::once(members.count())
                    .chain(std::iter::repeat_n(1, g.dim() - 1))
                    .collect();
                let _ = g.g_mul_(&scale.reshape(shape.as_slice()));
            }
        });
    }

    /// Applies one update to every parameter that has a gradient.
    pub fn step(&mut self) {
        self.step += 1;
        let AdamConfig {
            lr,
            beta1,
            beta2,
            eps,
        } = self.cfg;
        let bias1 = 1.0 - beta1.powi(self.step as i32);
        let bias2_sqrt = (1.0 - beta2.powi(self.step as i32)).sqrt();
        tch::no_grad(|| {
            for (((_, p), m), v) in self
                .params
                .iter_mut()
                .zip(&mut self.exp_avg)
                .zip(&mut self.exp_avg_sq)
            {
                let g = p.grad();
                if !g.defined() {
                    continue;
                }
                let _ = m.g_mul_scalar_(beta1);
                let _ = m.g_add_(&(&g * (1.0 - beta1)));
                let _ = v.g_mul_scalar_(beta2);
                let _ = v.addcmul_(&g, &(&g * (1.0 - beta2)));
                let denom = v.sqrt() / bias2_sqrt + eps;
                let _ = p.addcdiv_(&(&*m * (-lr / bias1)), &denom);
            }
        });
    }

    /// Moments as named tensors (`exp_avg/<name>`, `exp_avg_sq/<name>`).
    pub fn state_tensors(&self) -> Vec<(String, Tensor)> {
        let mut out = Vec::with_capacity(2 * self.params.len());
        for ((name, _), (m, v)) in self
            .params
            .iter()
            .zip(self.exp_avg.iter().zip(&self.exp_avg_sq))
        {
            out.push((format!("exp_avg/{name}"), m.shallow_clone()));
            out.push((format!("exp_avg_sq/{name}"), v.shallow_clone()));
        }
        out
    }

    /// Restores moments (as written by `state_tensors`, looked up with `prefix`) and the step count.
    pub fn load_state(
        &mut self,
        tensors: &HashMap<String, Tensor>,
        prefix: &str,
        step: i64,
    ) -> Result<(), AdamStateError> {
        for ((name, p), (m, v)) in self
            .params
            .iter()
            .zip(self.exp_avg.iter_mut().zip(self.exp_avg_sq.iter_mut()))
        {
            for (kind, dst) in [("exp_avg", m), ("exp_avg_sq", v)] {
                let key = format!("{prefix}{kind}/{name}");
                let src = tensors.get(&key).ok_or_else(|| AdamStateError {
                    name: key.clone(),
                    problem: "missing".into(),
                })?;
                if src.size() != p.size() {
                    let problem = format!("expected shape {:?}, got {:?}", p.size(), src.size());
                    return Err(AdamStateError { name: key, problem });
                }
                tch::no_grad(|| dst.copy_(src));
            }
        }
        self.step = step;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::Device;

    /// Two hand-computed steps of torch.optim.Adam(lr=0.1, eps=1e-8) on f(x) = x^2 from
    /// x = 1: g1 = 2, m1 = 0.2, v1 = 0.004, mhat = 2, vhat = 4, x1 = 1 - 0.1 * 2 / 2 = 0.9;
    /// g2 = 1.8, m2 = 0.36, v2 = 0.003996 + 0.00324 = 0.007236, mhat = 0.36/0.19 = 1.894737,
    /// vhat = 0.007236/0.001999 = 3.619810, x2 = 0.9 - 0.1 * 1.894737 / 1.902580 = 0.800412
    /// (torch 2.13 prints 0.8004122).
    #[test]
    fn matches_torch_adam_by_hand() {
        let x = Tensor::from_slice(&[1.0f32]).set_requires_grad(true);
        let mut opt = Adam::new(
            vec![("x".into(), x.shallow_clone())],
            AdamConfig::new(0.1, 1e-8),
        );
        for _ in 0..2 {
            opt.zero_grad();
            x.square().sum(Kind::Float).backward();
            opt.step();
        }
        assert!(
            (x.double_value(&[0]) - 0.800412).abs() < 1e-5,
            "{}",
            x.double_value(&[0])
        );
        let _ = Device::Cpu;
    }
}
