//! Retrace targets for multi-objective policy evaluation (appendix C.2, eq. 15;
//! Munos et al. 2016), one target per learned critic.
//!
//! `Q_ret(s_t, a_t) = Q'(s_t, a_t) + sum_{j=t}^{T-1} gamma^{j-t} (prod_{z=t+1}^{j} c_z) delta_j`,
//! `delta_j = r_j + gamma d_j V(s_{j+1}) - Q'(s_j, a_j)`, `V(s) = E_{pi_old}[Q'(s, a)]`,
//! `c_z = min(1, pi_old(a_z|s_z) / b(a_z|s_z))`.
//! Terminal masking: `d_j` (0 when s_{j+1} is terminal) removes the bootstrap and also
//! cuts the trace, so nothing after a terminal leaks into earlier targets. Computed by
//! the equivalent backward recursion
//! `A_{T-1} = delta_{T-1}`, `A_t = delta_t + gamma d_t c_{t+1} A_{t+1}`, `Q_ret_t = Q'_t + A_t`.
//! With T = 1 this is the one-step (expected-SARSA) TD target used for Deep Sea
//! Treasure (A.2).
//!
//! Shape legend: T snippet length, B snippets, C learned critics.

use tch::Tensor;

/// Inputs of `retrace_targets`; nothing here needs gradients.
#[derive(Debug)]
pub struct RetraceInputs<'a> {
    /// `[T, B, C]`: target-critic Q'(s_t, a_t) of the taken actions.
    pub q_taken: &'a Tensor,
    /// `[T, B, C]`: V(s_{t+1}) = E_{pi_old} Q'(s_{t+1}, .).
    pub v_next: &'a Tensor,
    /// `[T, B, C]`: rewards r_t per critic.
    pub rewards: &'a Tensor,
    /// `[T, B]`: env discount d_t (0 when s_{t+1} is terminal, else 1).
    pub discounts: &'a Tensor,
    /// `[T, B]`: truncated importance weights c_t (c_0 is not used).
    pub importance: &'a Tensor,
    /// Discount factor gamma.
    pub gamma: f64,
}

/// `c = min(1, exp(log pi_old - log b))`. # Shapes `[T, B], [T, B] -> [T, B]`.
pub fn importance_weights(target_log_probs: &Tensor, behaviour_log_probs: &Tensor) -> Tensor {
    (target_log_probs - behaviour_log_probs)
        .exp()
        .clamp_max(1.0)
}

/// Retrace targets. # Shapes `-> [T, B, C]`.
pub fn retrace_targets(inputs: &RetraceInputs<'_>) -> Tensor {
    let t_len = inputs.q_taken.size()[0];
    let discount = (inputs.discounts * inputs.gamma).unsqueeze(-1);
    let delta = inputs.rewards + &discount * inputs.v_next - inputs.q_taken;
    let trace = &discount
        * inputs
            .importance
            .unsqueeze(-1)
            .roll([-1i64].as_slice(), [0i64].as_slice());
    let mut advantages = Vec::with_capacity(t_len as usize);
    let mut next = delta.get(t_len - 1);
    advantages.push(next.shallow_clone());
    for t in (0..t_len - 1).rev() {
        next = delta.get(t) + trace.get(t) * &next;
        advantages.push(next.shallow_clone());
    }
    advantages.reverse();
    inputs.q_taken + Tensor::stack(&advantages, 0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::{Device, Kind};

    #[test]
    fn one_step_is_td() {
        let opts = (Kind::Float, Device::Cpu);
        let q = Tensor::randn([1, 4, 2], opts);
        let v = Tensor::randn([1, 4, 2], opts);
        let r = Tensor::randn([1, 4, 2], opts);
        let d = Tensor::from_slice(&[1.0f32, 0.0, 1.0, 1.0]).reshape([1, 4]);
        let c = Tensor::ones([1, 4], opts);
        let got = retrace_targets(&RetraceInputs {
            q_taken: &q,
            v_next: &v,
            rewards: &r,
            discounts: &d,
            importance: &c,
            gamma: 0.9,
        });
        let want = &r + d.unsqueeze(-1) * 0.9 * &v;
        assert!(got.allclose(&want, 1e-6, 1e-6, false));
    }
}
