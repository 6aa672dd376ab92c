//! The MO-V-MPO learner (appendix D), also running scalarized V-MPO (one value
//! function on `sum_k w_k r_k`, one epsilon; eq. 8 for mocap) through the same code.
//! It shares the networks, duals, trust-region fit and target schedule of MO-MPO
//! (`state.rs`); what differs is policy evaluation and step 1.
//!
//! One `step` on B on-policy unrolls of T steps (each used once) does, in order:
//! 1. **Policy evaluation** (D.1, eq. 21): the online critics give V_c at all
//!    N' = (T+1)B states; T-step targets `G_t = r_t + gamma d_t G'_{t+1}` with
//!    `G'_{t+1} = G_{t+1}` for a real next step and `V(s_{t+1})` at the unroll's end or
//!    before padding (so a truncated episode bootstraps and a terminated one does not);
//!    advantages `A = G - V` (no gradient); the critics are regressed on G (0.5 *
//!    squared error, mean over real steps, summed over heads), one Adam step.
//! 2. **Step 1** (D.2.1, eqs. 22-24) on the N = TB pairs: the top-k selection among
//!    real steps (one for all objectives by default, `vmpo.top_k`), the fit's weights
//!    and the temperature duals (`vmpo_estep::advantage_estep`).
//! 3. **Step 2** (D.2.2, eq. 25): weighted maximum likelihood of the taken actions with
//!    the decoupled trust region against pi_old, the target policy (Table 5 betas),
//!    both over the real steps only (padding is never acted from);
//!    one Adam step on the policy and one on the duals. A latent policy torso (A.3)
//!    evaluates online and target policies with the same latent noise.
//! 4. Every `target_update_period` steps pi_old is copied from the online policy.
//!
//! V-MPO uses each batch once (one update per learner step, the default). As an option
//! of ours, `vmpo.epochs` passes over `vmpo.minibatches` shuffled subsets of the
//! unrolls do steps 1-3 once per subset (PPO's reuse of on-policy data); all of a
//! step's updates share pi_old, and the targets and advantages are recomputed with the
//! current critic in every update. Each update's alpha bounds the KL only on average,
//! so such a step ends with its KL measured and, with `vmpo.project_step_kl`, pulled
//! back within beta (`vmpo_trust.rs`).
//!
//! **Populations**: every tensor is member-first (`[P, ..]`); each member's targets,
//! top-k, duals and policy fit use its own unrolls and real steps (gathered to the
//! widest member's count, `real_states::real_rows`), and each member shuffles its own
//! minibatches from its own stream, so member p computes what a learner of its config
//! alone computes on the same batches.
//!
//! Shape legend: P members, T unroll length, B unrolls, N = TB pairs (R: the widest
//! member's real ones), O observation size, D action dims, A discrete actions, K
//! objectives, C critics.

use super::batch::{SnippetBatch, StepShape};
use super::estep::StateMean;
use super::objectives::QSource;
use super::real_states::{gather_states, masked_half_mse, real_rows};
use super::state::{Critics, Learner, LearnerError, LearnerStats, PhaseTimings, to_vec};
use super::update::{PhaseClock, StepMeasures};
use super::vmpo_estep::{StepOneInputs, advantage_estep};
use crate::core::nets::PolicyOutput;
use crate::core::random::{Purpose, StreamKey};
use tch::{Device, Kind, Tensor};

/// Inputs of the T-step targets.
#[derive(Debug)]
pub struct UnrollTargetInputs<'a> {
    /// `[T, B, C]` rewards of the critic heads.
    pub rewards: &'a Tensor,
    /// `[T, B]`: 0 when s_{t+1} is terminal.
    pub discounts: &'a Tensor,
    /// `[T, B]`: 1 for real steps, 0 for padding.
    pub valid: &'a Tensor,
    /// `[T+1, B, C]`: V at s_0 .. s_T.
    pub values: &'a Tensor,
    /// gamma.
    pub gamma: f64,
}

/// T-step return targets of eq. 21 (see module docs). # Shapes `-> [T, B, C]`.
pub fn unroll_targets(x: &UnrollTargetInputs<'_>) -> Tensor {
    let t_len = x.rewards.size()[0];
    let mut next = x.values.get(t_len);
    let mut out = Vec::with_capacity(t_len as usize);
    for t in (0..t_len).rev() {
        let g = x.rewards.get(t) + (x.discounts.get(t) * x.gamma).unsqueeze(-1) * &next;
        if t > 0 {
            // What step t-1 bootstraps from: this step's target if real, else V(s_t).
            let real = x.valid.get(t).unsqueeze(-1);
            next = &real * &g + (1.0 - &real) * x.values.get(t);
        }
        out.push(g);
    }
    out.reverse();
    Tensor::stack(&out, 0)
}

/// Phase timings of two updates of one learner step, added.
fn summed(a: &PhaseTimings, b: &PhaseTimings) -> PhaseTimings {
    PhaseTimings {
        policy_evaluation_ms: a.policy_evaluation_ms + b.policy_evaluation_ms,
        e_step_ms: a.e_step_ms + b.e_step_ms,
        m_step_ms: a.m_step_ms + b.m_step_ms,
        target_update_ms: a.target_update_ms + b.target_update_ms,
    }
}

impl Learner {
    /// One MO-V-MPO learner step of every member on its checked batch of on-policy
    /// unrolls: `vmpo.epochs` passes, each over `vmpo.minibatches` disjoint subsets of
    /// each member's unrolls (one subset, the whole batch, by default), then the
    /// target update. The statistics are the last update's; the timings are summed
    /// over the updates.
    pub(super) fn vmpo_step(
        &mut self,
        batches: &[SnippetBatch],
    ) -> Result<Vec<LearnerStats>, LearnerError> {
        let (epochs, parts) = (self.cfg.vmpo.epochs, self.cfg.vmpo.minibatches as i64);
        let (t_len, b) = (batches[0].len(), batches[0].batch_size());
        let several = epochs as i64 * parts > 1;
        let start = (several && self.cfg.vmpo.project_step_kl).then(|| self.policy_parameters());
        let mut measured: Option<StepMeasures> = None;
        for epoch in 0..epochs {
            let subsets: Vec<SnippetBatch> = if parts == 1 {
                vec![self.stack_batches(batches, t_len).0]
            } else {
                // A fresh shuffle per member and epoch (as PPO), keyed by the member's
                // (seed, step, epoch).
                let orders: Vec<Vec<Tensor>> = self
                    .member_cfgs
                    .iter()
                    .map(|c| {
                        StreamKey::new(c.seed, Purpose::Minibatches, epoch as u64)
                            .at(self.step)
                            .uniform(&[b], Device::Cpu)
                            .argsort(0, false)
                            .chunk(parts, 0)
                    })
                    .collect();
                (0..parts as usize)
                    .map(|i| {
                        let subset: Vec<SnippetBatch> = batches
                            .iter()
                            .zip(&orders)
                            .map(|(batch, order)| {
                                batch.select_unrolls(
                                    &order[i].to_device(batch.observations.device()),
                                )
                            })
                            .collect();
                        self.stack_batches(&subset, t_len).0
                    })
                    .collect()
            };
            for subset in &subsets {
                let m = self.vmpo_update(subset);
                measured = Some(match measured {
                    None => m,
                    Some(previous) => StepMeasures {
                        timings: summed(&previous.timings, &m.timings),
                        ..m
                    },
                });
            }
        }
        let end = several.then(|| {
            let whole = self.stack_batches(batches, t_len).0;
            let p = self.members.count();
            let obs = whole
                .observations
                .reshape([p, (t_len + 1) * b, -1])
                .narrow(1, 0, t_len * b);
            self.end_step(&obs, &whole.valid.reshape([p, -1]), start.as_ref())
        });
        let mut stats = self.finish_members(measured.expect("vmpo.epochs >= 1 is validated"))?;
        // A step of several updates reports its policy KL at its end (after the
        // projection), the number its beta bounds, rather than before its last update.
        if let Some(end) = end {
            let rows = to_vec(&end.kl);
            let width = rows.len() / stats.len().max(1);
            for (s, row) in stats.iter_mut().zip(rows.chunks(width.max(1))) {
                s.policy_kl = row.to_vec();
            }
        }
        Ok(stats)
    }

    /// One update (critic, step 1, step 2, duals) on the members' unrolls of `batch`
    /// (member-first: `[P, T, B, ..]`).
    fn vmpo_update(&mut self, batch: &SnippetBatch) -> StepMeasures {
        let mut clock = PhaseClock::start(self.device);
        let shape = StepShape::of(batch, self.bound.critic_names.len() as i64);

        // 1. Policy evaluation (D.1, eq. 21).
        let eval = self.evaluate_values(batch, shape);
        clock.policy_evaluation_done();

        // 2. Step 1 (D.2.1): per-objective top-k weights and temperature duals.
        let k = self.bound.objectives.len() as i64;
        let estep = advantage_estep(&StepOneInputs {
            advantages: &self.objective_advantages(&eval.advantages),
            eligible: &eval.valid,
            temperature: &self.duals.temperature().reshape([-1, 1, k]),
            epsilon: &self.epsilon.reshape([-1, 1, k]),
            fraction: self.cfg.vmpo.top_k_fraction,
            rule: self.cfg.vmpo.top_k,
        });
        let pairs = real_pairs(batch, shape, &eval, &estep.fit_weights);
        clock.e_step_done();

        // 3. Step 2 (D.2.2, eq. 25) and dual updates.
        let policy_kl = self.fit_taken_actions(&pairs, &estep.temperature_loss);
        clock.m_step_done();

        StepMeasures {
            critic_loss: eval.critic_loss,
            estep_kl: estep.kl,
            value_mean: eval.value_mean,
            policy_kl,
            timings: clock.timings(),
        }
    }

    /// Policy evaluation (D.1, eq. 21): V_c at every state, the T-step targets and
    /// advantages, and one Adam step of the critics on the targets.
    fn evaluate_values(&mut self, batch: &SnippetBatch, shape: StepShape) -> ValueEvaluation {
        let (p, t_len, b, heads) = (shape.members, shape.t_len, shape.b, shape.heads);
        let n = shape.pairs();
        let Critics::V { online: critic } = &self.nets.critics else {
            unreachable!("V-MPO learners are built with state-value critics")
        };
        let values = critic
            .forward_members(&batch.observations.reshape([p, shape.states(), -1]))
            .reshape([p, t_len + 1, b, heads]);
        let targets = tch::no_grad(|| self.member_unroll_targets(batch, &values.detach(), shape));
        let v_taken = values.narrow(1, 0, t_len);
        let advantages = (&targets - v_taken.detach()).reshape([p, n, heads]);
        let valid = batch.valid.reshape([p, n]);
        let critic_loss = masked_half_mse(&(v_taken - &targets).reshape([p, n, heads]), &valid);
        let real_steps = valid.sum_dim_intlist(-1, true, Kind::Float).clamp_min(1.0);
        let value_mean = (values.detach().narrow(1, 0, t_len).reshape([p, n, heads])
            * valid.unsqueeze(-1))
        .sum_dim_intlist(1, false, Kind::Float)
            / &real_steps;
        self.update_critics(&critic_loss.sum(Kind::Float));
        ValueEvaluation {
            advantages,
            valid,
            real_steps,
            value_mean,
            critic_loss,
        }
    }

    /// Each member's T-step targets (eq. 21) from its unrolls and `values
    /// [P, T+1, B, C]`, `[P, T, B, C]`.
    fn member_unroll_targets(
        &self,
        batch: &SnippetBatch,
        values: &Tensor,
        shape: StepShape,
    ) -> Tensor {
        let (p, t_len, b, heads) = (shape.members, shape.t_len, shape.b, shape.heads);
        // The targets run along time: members join the unroll axis.
        let time_first = |t: &Tensor| {
            let size = t.size();
            let mut shape = vec![size[1], p * b];
            shape.extend_from_slice(&size[3..]);
            t.transpose(0, 1).reshape(shape.as_slice())
        };
        unroll_targets(&UnrollTargetInputs {
            rewards: &time_first(&self.critic_rewards(&batch.rewards)),
            discounts: &time_first(&batch.discounts),
            valid: &time_first(&batch.valid),
            values: &time_first(values),
            gamma: self.settings.discount,
        })
        .reshape([t_len, p, b, heads])
        .transpose(0, 1)
    }

    /// The advantages of the bound objectives, `[P, N, C] -> [P, N, K]`: each learned
    /// objective's critic head.
    fn objective_advantages(&self, advantages: &Tensor) -> Tensor {
        let columns: Vec<Tensor> = self
            .bound
            .objectives
            .iter()
            .map(|o| match o.source {
                QSource::Critic { head } => advantages.select(-1, head as i64),
                QSource::ActionNorm | QSource::OutOfBounds => {
                    unreachable!("bind_config rejects closed-form objectives for V-MPO")
                }
            })
            .collect();
        Tensor::stack(&columns, -1)
    }

    /// Step 2 (D.2.2, eq. 25): weighted maximum likelihood of the taken actions under
    /// the decoupled trust region against pi_old, plus the temperature loss; one Adam
    /// step on the policy and one on the duals. A latent torso evaluates online and
    /// target policies with the same latent noise, so that their KL is the heads'.
    /// Returns the policy KL parts before the update, `[P, parts]`.
    fn fit_taken_actions(&mut self, pairs: &RealPairs, temperature_loss: &Tensor) -> Tensor {
        let noise = self
            .nets
            .policy
            .latent_noise(pairs.obs.size()[1], &mut self.stream(Purpose::LatentNoise));
        let target_out = tch::no_grad(|| {
            self.nets
                .target_policy
                .forward_members(&pairs.obs, noise.as_ref())
        });
        let online_out = self.nets.policy.forward_members(&pairs.obs, noise.as_ref());
        let (actions, weights) = match &online_out {
            PolicyOutput::Gaussian(_) => (pairs.taken.unsqueeze(1), pairs.weights.unsqueeze(1)),
            PolicyOutput::Categorical(logits) => {
                let one_hot = pairs
                    .taken
                    .one_hot(logits.size()[2])
                    .to_kind(Kind::Float)
                    .transpose(1, 2);
                (
                    pairs.taken.shallow_clone(),
                    one_hot * pairs.weights.unsqueeze(1),
                )
            }
        };
        self.fit_policy(
            &online_out,
            &target_out,
            &actions,
            &weights,
            temperature_loss,
            StateMean::Members(&pairs.state_weight),
            None,
        )
    }
}

/// What policy evaluation leaves for the policy update (N = TB pairs).
struct ValueEvaluation {
    /// `[P, N, C]`: A = G - V, no gradient.
    advantages: Tensor,
    /// `[P, N]`: 1 at real steps, 0 at padding.
    valid: Tensor,
    /// `[P, 1]`: each member's count of real steps (at least 1).
    real_steps: Tensor,
    /// `[P, C]`: mean V_c over each member's real steps, before the update.
    value_mean: Tensor,
    /// `[P, C]`: the critics' losses before the update.
    critic_loss: Tensor,
}

/// Step 2's data: each member's real steps (gathered to the widest member's count R),
/// their taken actions and fit weights.
struct RealPairs {
    /// `[P, R, O]`.
    obs: Tensor,
    /// `[P, R, D]` f32 or `[P, R]` i64.
    taken: Tensor,
    /// `[P, R]`: step 1's fit weights, scaled by the member's count of real steps.
    weights: Tensor,
    /// `[P, R]`: each member's mean over its real steps (0 at the copies).
    state_weight: Tensor,
}

/// Step 2 fits the policy, and bounds its KL, at each member's real steps only:
/// padding carries no weight and is never acted from.
fn real_pairs(
    batch: &SnippetBatch,
    shape: StepShape,
    eval: &ValueEvaluation,
    fit_weights: &Tensor,
) -> RealPairs {
    let obs = batch
        .observations
        .reshape([shape.members, shape.states(), -1])
        .narrow(1, 0, shape.pairs());
    let taken = batch.actions.flatten(1, 2);
    let real = real_rows(&eval.valid.gt(0.5));
    let gather = |t: &Tensor| match &real.index {
        None => t.shallow_clone(),
        Some(index) => gather_states(t, index, 1),
    };
    RealPairs {
        obs: gather(&obs),
        taken: gather(&taken),
        // fit_policy averages over each member's real steps; the weights sum to 1
        // over them.
        weights: gather(fit_weights) * &eval.real_steps,
        state_weight: real.weight,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn targets_bootstrap_at_the_end_and_before_padding_but_not_after_termination() {
        // One head, gamma 0.5. Unroll 0: steps 0-2 real, none terminal; V(s_3) = 8.
        // Unroll 1: step 0 terminal, steps 1-2 padding.
        // Unroll 2: step 0 truncated (discount 1), steps 1-2 padding, V(s_1) = 4.
        let t = |v: &[f32]| Tensor::from_slice(v);
        let rewards = t(&[1.0, 5.0, 1.0, 2.0, 0.0, 0.0, 3.0, 0.0, 0.0]).reshape([3, 3, 1]);
        let discounts = t(&[1.0, 0.0, 1.0, 1.0, 0.0, 0.0, 1.0, 0.0, 0.0]).reshape([3, 3]);
        let valid = t(&[1.0, 1.0, 1.0, 1.0, 0.0, 0.0, 1.0, 0.0, 0.0]).reshape([3, 3]);
        let values =
            t(&[0.0, 0.0, 0.0, 0.0, 9.0, 4.0, 0.0, 9.0, 9.0, 8.0, 9.0, 9.0]).reshape([4, 3, 1]);
        let g = unroll_targets(&UnrollTargetInputs {
            rewards: &rewards,
            discounts: &discounts,
            valid: &valid,
            values: &values,
            gamma: 0.5,
        });
        // Unroll 0 (rewards 1, 2, 3): G_2 = 3 + 0.5 * 8 = 7, G_1 = 2 + 3.5 = 5.5,
        // G_0 = 1 + 2.75 = 3.75. Unroll 1: G_0 = 5 (terminal).
        // Unroll 2: G_0 = 1 + 0.5 * V(s_1) = 1 + 2 = 3.
        assert!((g.double_value(&[0, 0, 0]) - 3.75).abs() < 1e-6, "{g}");
        assert!((g.double_value(&[0, 1, 0]) - 5.0).abs() < 1e-6, "{g}");
        assert!((g.double_value(&[0, 2, 0]) - 3.0).abs() < 1e-6, "{g}");
    }
}
