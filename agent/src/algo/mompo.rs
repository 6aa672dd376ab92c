//! The MO-MPO learner (Algorithm 3), also running scalarized MPO (one critic on
//! `sum_k w_k r_k`, one epsilon) through the same code.
//!
//! One `step` on a `SnippetBatch` of B snippets of length T does, in order:
//! 1. **Policy evaluation** (C.2, eq. 15). The target policy draws M actions at each of
//!    the N = (T+1)B states (noise from the learner's `NoiseSource`; all A actions for
//!    categorical policies) and the target critic scores them: `Q' [M, N, C]`. V(s) is
//!    their mean (pi_old-weighted sum for categorical). Retrace targets for the T*B
//!    taken pairs use the target critic, the target policy's log-probabilities and
//!    c = min(1, pi_old/b). The online critic is regressed on them (0.5 * squared
//!    error, mean over real pairs, summed over heads), one Adam step. Padding after
//!    an episode's end (`valid` 0) is not regressed.
//! 2. **E-step** (eqs. 32-34) on the same samples at the real states (`real_states`):
//!    the states acted from, plus a last state bootstrapped into from a real,
//!    non-terminal step; padding and terminal observations are never acted from, so
//!    no policy is fitted there. Q_k is the target critic's head for learned
//!    objectives and `-||a_env||_2` for the action norm, with a_env the action the env
//!    executes for the sample (clipped and mapped onto its Box, as the env's reward
//!    sees it); weights q_k and the temperature duals (`estep.rs`).
//! 3. **M-step** (eqs. 16-20): weighted maximum likelihood with the decoupled trust
//!    region (`mstep.rs`); one Adam step on the policy and one on all duals, then the
//!    dual floor (`dual.rs`).
//! 4. Every `target_update_period` steps the target networks are copied from the online ones.
//!
//! **ε-conditioned** (`learner.conditioning`, `preferences.rs`): every snippet is trained
//! at one grid point ε_g, drawn for it (relabelling) or the one it was collected with;
//! its states' preference features say which, so policy, critics and Retrace all see
//! (s, ε_g), and the E-step solves eq. 34 per grid point with that point's eta_g.
//! The M-step's trust region (alpha) is shared by all grid points.
//!
//! Shape legend: T snippet length, B snippets, N = (T+1)B states, M samples, D action
//! dims, A discrete actions, K objectives, C critics.

use super::batch::SnippetBatch;
use super::estep::{EStepOutput, StateMean, exact_estep_with, sampled_estep_with};
use super::objectives::{QSource, action_norm_q};
use super::preferences::{StatePreferences, collected_index, relabel};
use super::retrace::{RetraceInputs, importance_weights, retrace_targets};
use super::state::{Critics, Learner, LearnerError, LearnerStats, PhaseTimings, ms_since, to_vec};
use super::update::StepMeasures;
use crate::nets::{ActionKind, GaussianParams, PolicyOutput};
use crate::random::Purpose;
use std::time::Instant;
use tch::{Kind, Tensor};

/// Indices of the real states among the N = (T+1)B rows of a snippet batch, or `None`
/// when every row is real. Row (t, b) is real when step t is real (`valid`), or when
/// step t-1 is real and not terminal (s_t is then the state it bootstraps from: the
/// next state of a step, or the last observation of a time-limited episode).
/// # Shapes
/// `valid [T, B]`, `discounts [T, B] -> [R] i64`.
pub fn real_states(valid: &Tensor, discounts: &Tensor) -> Option<Tensor> {
    let b = valid.size()[1];
    let acted = Tensor::cat(
        &[valid.shallow_clone(), valid.zeros_like().narrow(0, 0, 1)],
        0,
    );
    let bootstrapped = Tensor::cat(&[valid.zeros_like().narrow(0, 0, 1), valid * discounts], 0);
    let real = acted.maximum(&bootstrapped).gt(0.5).reshape([-1]);
    if real.all().int64_value(&[]) == 1 {
        return None;
    }
    debug_assert_eq!(real.size()[0] % b, 0);
    Some(real.nonzero().squeeze_dim(-1))
}

/// `0.5 * mean over real rows of err^2`, per column.
/// # Shapes
/// `err [N, C]`, `valid [N]` (1 real, 0 padding) `-> [C]`.
pub fn masked_half_mse(err: &Tensor, valid: &Tensor) -> Tensor {
    let real = valid.sum(Kind::Float).clamp_min(1.0);
    (err.square() * valid.unsqueeze(-1)).sum_dim_intlist(0, false, Kind::Float) / real * 0.5
}

impl Learner {
    /// Q-values for the E-step, `[M, N, K]`, from critic heads and closed forms.
    fn estep_q(&self, critic_q: &Tensor, actions: &Tensor) -> Tensor {
        let columns: Vec<Tensor> = self
            .bound
            .objectives
            .iter()
            .map(|o| match o.source {
                QSource::Critic { head } => critic_q.select(-1, head as i64),
                QSource::ActionNorm => action_norm_q(actions, self.dims.action_bounds.as_ref()),
            })
            .collect();
        Tensor::stack(&columns, -1)
    }

    /// One MO-MPO step (critic update, E-step, M-step, duals, target update) on a
    /// checked batch.
    pub(super) fn mpo_step(&mut self, batch: &SnippetBatch) -> Result<LearnerStats, LearnerError> {
        let start = Instant::now();
        let batch = batch.to_device(self.device);
        let (t_len, b) = (batch.len(), batch.batch_size());
        let n = (t_len + 1) * b;
        let (observations, preferences) = self.preferences_of(&batch.observations, t_len);
        let obs_all = observations.reshape([n, self.dims.obs_dim]);
        let obs_taken = obs_all.narrow(0, 0, t_len * b);
        let act_taken = batch.actions.flatten(0, 1);
        let heads = self.bound.critic_names.len() as i64;
        let noise = match self.dims.action {
            ActionKind::Continuous { dim } => Some(self.noise.standard_normal(
                &[self.cfg.mpo.num_samples, n, dim],
                self.device,
                self.step,
            )?),
            ActionKind::Discrete { .. } => None,
        };
        let Critics::Q {
            online: critic,
            target: target_critic,
            ..
        } = &self.critics
        else {
            unreachable!("MPO learners are built with Q critics")
        };

        // 1. Policy evaluation with Retrace (C.2).
        let eval = tch::no_grad(|| {
            let target_out = self.target_policy.forward(&obs_all);
            let (samples, critic_q, v_all, log_prior) = match &target_out {
                PolicyOutput::Gaussian(g) => {
                    let noise = noise
                        .as_ref()
                        .expect("Gaussian policies have continuous actions");
                    let samples = g.sample_from(noise);
                    let q = target_critic.forward_samples(&obs_all, &samples);
                    let v = q.mean_dim(0, false, Kind::Float);
                    (samples, q, v, None)
                }
                PolicyOutput::Categorical(logits) => {
                    let q = target_critic.forward_all_actions(&obs_all);
                    let log_prior = logits.log_softmax(-1, Kind::Float).transpose(0, 1);
                    let v =
                        (log_prior.exp().unsqueeze(-1) * &q).sum_dim_intlist(0, false, Kind::Float);
                    let a = logits.size()[1];
                    let all = Tensor::arange(a, (Kind::Int64, self.device))
                        .unsqueeze(1)
                        .expand([a, n], false);
                    (all, q, v, Some(log_prior))
                }
            };
            let v_next = v_all.reshape([t_len + 1, b, heads]).narrow(0, 1, t_len);
            let q_taken = target_critic
                .forward(&obs_taken, &act_taken)
                .reshape([t_len, b, heads]);
            let target_log_probs = match &target_out {
                PolicyOutput::Gaussian(g) => PolicyOutput::Gaussian(GaussianParams {
                    mean: g.mean.narrow(0, 0, t_len * b),
                    std: g.std.narrow(0, 0, t_len * b),
                }),
                PolicyOutput::Categorical(l) => {
                    PolicyOutput::Categorical(l.narrow(0, 0, t_len * b))
                }
            }
            .log_prob(&act_taken)
            .reshape([t_len, b]);
            // c = 0 at padding cuts the trace exactly (PAD_LOG_PROB alone leaves ~e^-60).
            let importance =
                importance_weights(&target_log_probs, &batch.behaviour_log_probs) * &batch.valid;
            let rewards = self.critic_rewards(&batch.rewards);
            let targets = retrace_targets(&RetraceInputs {
                q_taken: &q_taken,
                v_next: &v_next,
                rewards: &rewards,
                discounts: &batch.discounts,
                importance: &importance,
                gamma: self.cfg.mpo.discount,
            });
            (
                target_out,
                samples,
                critic_q,
                log_prior,
                targets.reshape([t_len * b, heads]),
            )
        });
        let (target_out, samples, critic_q, log_prior, targets) = eval;
        let q_online = critic.forward(&obs_taken, &act_taken);
        let per_head = masked_half_mse(&(q_online - &targets), &batch.valid.reshape([t_len * b]));
        self.update_critics(&per_head.sum(Kind::Float));
        let policy_evaluation_ms = ms_since(start, self.device);

        // The E- and M-steps see only real states (all of them, in most batches).
        let real = real_states(&batch.valid, &batch.discounts);
        let preferences = match (&real, preferences) {
            (Some(index), Some(p)) => Some(p.rows(index, &self.conditioned_epsilon())),
            (_, p) => p,
        };
        let (obs_real, target_out, samples, critic_q, log_prior) = match &real {
            None => (obs_all, target_out, samples, critic_q, log_prior),
            Some(index) => (
                obs_all.index_select(0, index),
                target_out.rows(index),
                samples.index_select(1, index),
                critic_q.index_select(1, index),
                log_prior.map(|p| p.index_select(1, index)),
            ),
        };

        // 2. E-step (eqs. 32-34).
        let start = Instant::now();
        let q = self.estep_q(&critic_q, &samples);
        let estep = self.estep(&q, log_prior.as_ref(), preferences.as_ref());
        let weights = estep.weights.sum_dim_intlist(-1, false, Kind::Float);
        let e_step_ms = ms_since(start, self.device);

        // 3. M-step (eqs. 16-20) and dual updates.
        let start = Instant::now();
        let online_out = self.policy.forward(&obs_real);
        let policy_kl = self.fit_policy(
            &online_out,
            &target_out,
            &samples,
            &weights,
            &estep.temperature_loss,
        );
        let m_step_ms = ms_since(start, self.device);

        // 4. Target networks.
        self.finish_step(StepMeasures {
            critic_loss: per_head,
            estep_kl: estep.kl,
            value_mean: q.mean_dim([0i64, 1].as_slice(), false, Kind::Float),
            policy_kl,
            timings: PhaseTimings {
                policy_evaluation_ms,
                e_step_ms,
                m_step_ms,
                target_update_ms: 0.0,
            },
        })
    }

    /// The batch's observations `[T+1, B, O]` as the step trains on them, and for an
    /// ε-conditioned learner the grid point of each of the N = (T+1)B states: drawn
    /// per snippet from the `LearnerPreference` stream at this step and written into
    /// the features (relabelling), or read back from them.
    fn preferences_of(
        &self,
        observations: &Tensor,
        t_len: i64,
    ) -> (Tensor, Option<StatePreferences>) {
        let Some(c) = &self.conditioned else {
            return (observations.shallow_clone(), None);
        };
        let (observations, index) = if c.relabel {
            let b = observations.size()[1];
            let mut stream = self.stream(Purpose::LearnerPreference);
            let drawn: Vec<i64> = (0..b).map(|_| c.grid.draw(&mut stream) as i64).collect();
            let index = Tensor::from_slice(&drawn).to_device(self.device);
            (relabel(observations, &index, &c.features), index)
        } else {
            (
                observations.shallow_clone(),
                collected_index(observations, &c.features),
            )
        };
        // Rows are (t, b) t-major, so every state of snippet b has its index.
        let per_state = index.repeat([t_len + 1]);
        (
            observations,
            Some(StatePreferences::new(per_state, &c.epsilon)),
        )
    }

    /// The E-step on `q [M, N, K]` (with `log_prior [A, N]`: exact, categorical), with
    /// one ε and eta per objective, or each state's grid point's.
    fn estep(
        &self,
        q: &Tensor,
        log_prior: Option<&Tensor>,
        preferences: Option<&StatePreferences>,
    ) -> EStepOutput {
        let temperature = self.duals.temperature();
        let (temperature, epsilon, states) = match preferences {
            None => (
                temperature,
                self.epsilon.shallow_clone(),
                StateMean::Uniform,
            ),
            Some(p) => (
                p.temperature(&temperature.reshape([-1, self.epsilon.size()[0]])),
                p.epsilon.shallow_clone(),
                StateMean::PerGridPoint(&p.state_weight),
            ),
        };
        match log_prior {
            None => sampled_estep_with(q, &temperature, &epsilon, states),
            Some(prior) => exact_estep_with(q, prior, &temperature, &epsilon, states),
        }
    }

    /// `[G, K]` ε table of a conditioned learner.
    fn conditioned_epsilon(&self) -> Tensor {
        self.conditioned
            .as_ref()
            .map(|c| c.epsilon.shallow_clone())
            .expect("only conditioned learners have state preferences")
    }

    /// Policy improvement only (E-step, M-step, duals) on given Q-values of the target
    /// policy's samples, for bandits and tests where Q is known in closed form.
    /// `q_fn` maps sampled actions `[M, N, D]` to Q `[M, N, K]`. An ε-conditioned
    /// learner trains each state at a grid point, as `step` trains each snippet
    /// (`obs [N, O + F]` carries the features it reads back or overwrites).
    /// Returns (temperatures, policy KL (KL_mu, KL_Sigma) before the update).
    pub fn improve_policy_with(
        &mut self,
        obs: &Tensor,
        q_fn: impl Fn(&Tensor) -> Tensor,
    ) -> (Vec<f32>, Vec<f32>) {
        // Each state is a snippet of length 0: its own grid point.
        let (obs, preferences) = self.preferences_of(&obs.to_device(self.device).unsqueeze(0), 0);
        let obs = obs.squeeze_dim(0);
        let target_out = tch::no_grad(|| self.target_policy.forward(&obs));
        let PolicyOutput::Gaussian(target) = &target_out else {
            panic!("improve_policy_with needs a Gaussian policy");
        };
        let shape = [&[self.cfg.mpo.num_samples][..], &target.mean.size()[..]].concat();
        let noise = self
            .stream(Purpose::LearnerNoise)
            .normal(&shape, self.device);
        let samples = tch::no_grad(|| target.sample_from(&noise));
        let q = q_fn(&samples);
        let estep = self.estep(&q, None, preferences.as_ref());
        let online_out = self.policy.forward(&obs);
        let weights = estep.weights.sum_dim_intlist(-1, false, Kind::Float);
        let policy_kl = self.fit_policy(
            &online_out,
            &target_out,
            &samples,
            &weights,
            &estep.temperature_loss,
        );
        self.advance_targets().expect("same layout");
        (self.duals.values().0, to_vec(&policy_kl))
    }
}
