//! MO-MPO's policy evaluation (C.2, eq. 15; step 1 of `mompo.rs`): the target policy's
//! M sampled actions at every state (all A actions, categorical) scored by the target
//! critic, V(s) from those scores, Retrace targets for the taken pairs, and the online
//! critic's regression on them.
//!
//! Shape legend: P members, T snippet length, B snippets, N = (T+1)B states, O
//! observation size, M samples, D action dims, A discrete actions, C critics.

use tch::{Kind, Tensor};

use super::batch::{SnippetBatch, StepShape};
use super::real_states::masked_half_mse;
use super::retrace::{RetraceInputs, importance_weights, retrace_targets};
use super::state::{Critics, Learner, LearnerError};
use crate::core::nets::{ActionKind, MultiCritic, PolicyOutput};

/// The target networks at every state: pi_old there, its M sampled actions (all A
/// actions, categorical) scored by the target critic, and V(s) from those scores.
pub(super) struct TargetSamples {
    /// `[P, N, O]`: the states.
    pub(super) obs: Tensor,
    /// pi_old at the N states.
    pub(super) policy: PolicyOutput,
    /// `[P, M, N, D]` sampled actions, or `[P, A, N]` every action's index.
    pub(super) actions: Tensor,
    /// `[P, M, N, C]` (`[P, A, N, C]`): Q' of `actions`.
    pub(super) q: Tensor,
    /// `[P, N, C]`: the mean of `q` over the samples (pi_old-weighted, categorical).
    pub(super) v: Tensor,
    /// `[P, A, N]`: log pi_old of every action (categorical only, for the exact E-step).
    pub(super) log_prior: Option<Tensor>,
}

/// The MO-MPO critics.
struct QCritics<'a> {
    online: &'a MultiCritic,
    target: &'a MultiCritic,
}

impl Learner {
    /// The online Q critics' values of `actions` at `obs`, untracked: for reading a
    /// trained learner's critics (`scripts/probe_critic.py` transcribes them, and
    /// `agent/tests/python_policy.rs` checks that the two agree). `None` for a MO-V-MPO
    /// learner, whose critics value states.
    /// # Shapes
    /// `obs [P, N, O]` (an ε-conditioned learner's preference features appended),
    /// `actions [P, M, N, D] f32 | [P, M, N] i64 -> [P, M, N, C]`.
    pub fn q_values(&self, obs: &Tensor, actions: &Tensor) -> Option<Tensor> {
        let Critics::Q { online, .. } = &self.nets.critics else {
            return None;
        };
        Some(tch::no_grad(|| {
            online.forward_samples_members(obs, actions)
        }))
    }

    /// The online and target Q critics.
    fn q_critics(&self) -> QCritics<'_> {
        let Critics::Q { online, target, .. } = &self.nets.critics else {
            unreachable!("MPO learners are built with Q critics")
        };
        QCritics { online, target }
    }

    /// Every member's Gaussian sampling noise for `n` states, `[P, M, n, D]`; none for
    /// categorical policies, whose E-step sums over all actions.
    pub(super) fn sampling_noise(&mut self, n: i64) -> Result<Option<Tensor>, LearnerError> {
        match self.dims.action {
            ActionKind::Continuous { dim } => Ok(Some(self.member_noise(&[
                self.cfg.mpo.num_samples,
                n,
                dim,
            ])?)),
            ActionKind::Discrete { .. } => Ok(None),
        }
    }

    /// pi_old's samples at every state `obs [P, N, O]` and the target critic's scores
    /// of them (C.2, eq. 15): Gaussian samples from `noise`, or every discrete action.
    pub(super) fn sample_target(&self, obs: Tensor, noise: Option<&Tensor>) -> TargetSamples {
        let critic = self.q_critics().target;
        let policy = self.nets.target_policy.forward_members(&obs, None);
        match &policy {
            PolicyOutput::Gaussian(g) => {
                let noise = noise.expect("Gaussian policies have continuous actions");
                let actions = g.mean.unsqueeze(1) + noise * g.std.unsqueeze(1);
                let q = critic.forward_samples_members(&obs, &actions);
                let v = q.mean_dim(1, false, Kind::Float);
                TargetSamples {
                    obs,
                    policy,
                    actions,
                    q,
                    v,
                    log_prior: None,
                }
            }
            PolicyOutput::Categorical(logits) => {
                let q = critic.forward_all_actions_members(&obs);
                let log_prior = logits.log_softmax(-1, Kind::Float).transpose(1, 2);
                let v = (log_prior.exp().unsqueeze(-1) * &q).sum_dim_intlist(1, false, Kind::Float);
                let size = logits.size();
                let (p, n, a) = (size[0], size[1], size[2]);
                let actions = Tensor::arange(a, (Kind::Int64, self.device))
                    .reshape([1, a, 1])
                    .expand([p, a, n], false);
                TargetSamples {
                    obs,
                    policy,
                    actions,
                    q,
                    v,
                    log_prior: Some(log_prior),
                }
            }
        }
    }

    /// Regresses the online critics on the Retrace targets of the taken pairs (0.5 *
    /// squared error, mean over real pairs, summed over heads), one Adam step.
    /// Returns each member's loss per head, `[P, C]`.
    pub(super) fn regress_critics(
        &mut self,
        batch: &SnippetBatch,
        target: &TargetSamples,
        shape: StepShape,
    ) -> Tensor {
        let (p, pairs) = (shape.members, shape.pairs());
        let obs_taken = target.obs.narrow(1, 0, pairs);
        let act_taken = batch.actions.flatten(1, 2);
        let targets = tch::no_grad(|| self.retrace(batch, &obs_taken, &act_taken, target, shape));
        let q_online = self
            .q_critics()
            .online
            .forward_members(&obs_taken, &act_taken);
        let per_head = masked_half_mse(&(q_online - &targets), &batch.valid.reshape([p, pairs]));
        self.update_critics(&per_head.sum(Kind::Float));
        per_head
    }

    /// Retrace targets (C.2, eq. 15) of the taken pairs, `[P, TB, C]`: the target
    /// critic, the target policy's log-probabilities and c = min(1, pi_old/b).
    fn retrace(
        &self,
        batch: &SnippetBatch,
        obs_taken: &Tensor,
        act_taken: &Tensor,
        target: &TargetSamples,
        shape: StepShape,
    ) -> Tensor {
        let (p, t_len, b, heads) = (shape.members, shape.t_len, shape.b, shape.heads);
        let pairs = shape.pairs();
        let v_next = target
            .v
            .reshape([p, t_len + 1, b, heads])
            .narrow(1, 1, t_len);
        let q_taken = match &target.log_prior {
            // Every action's Q is scored already: the taken ones are a gather.
            Some(_) => {
                let index = act_taken
                    .reshape([p, 1, pairs, 1])
                    .expand([p, 1, pairs, heads], false);
                target
                    .q
                    .narrow(2, 0, pairs)
                    .gather(1, &index, false)
                    .squeeze_dim(1)
            }
            None => self
                .q_critics()
                .target
                .forward_members(obs_taken, act_taken),
        }
        .reshape([p, t_len, b, heads]);
        let target_log_probs = target
            .policy
            .narrow_states(pairs)
            .log_prob(act_taken)
            .reshape([p, t_len, b]);
        // c = 0 at padding cuts the trace exactly (PAD_LOG_PROB alone leaves ~e^-60).
        let importance =
            importance_weights(&target_log_probs, &batch.behaviour_log_probs) * &batch.valid;
        // Retrace runs along time: members join the batch axis.
        let time_first = |t: &Tensor| t.transpose(0, 1);
        let targets = retrace_targets(&RetraceInputs {
            q_taken: &time_first(&q_taken),
            v_next: &time_first(&v_next),
            rewards: &time_first(&self.critic_rewards(&batch.rewards)),
            discounts: &time_first(&batch.discounts),
            importance: &time_first(&importance),
            gamma: self.cfg.mpo.discount,
        });
        time_first(&targets).reshape([p, pairs, heads])
    }
}
