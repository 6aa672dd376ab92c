//! The MO-MPO learner (Algorithm 3), also running scalarized MPO (one critic on
//! `sum_k w_k r_k`, one epsilon) through the same code.
//!
//! One `step` on a `SnippetBatch` of B snippets of length T does, in order:
//! 1. **Policy evaluation** (C.2, eq. 15; `mpo_eval.rs`). The target policy draws M actions at each of
//!    the N = (T+1)B states (noise from the learner's `NoiseSource`; all A actions for
//!    categorical policies) and the target critic scores them: `Q' [M, N, C]`. V(s) is
//!    their mean (pi_old-weighted sum for categorical). Retrace targets for the T*B
//!    taken pairs use the target critic (categorical: its scores of all actions,
//!    gathered), the target policy's log-probabilities and
//!    c = min(1, pi_old/b). The online critic is regressed on them (0.5 * squared
//!    error, mean over real pairs, summed over heads), one Adam step. Padding after
//!    an episode's end (`valid` 0) is not regressed.
//! 2. **E-step** (eqs. 32-34) on the same samples at the real states (`real_states`):
//!    the states acted from, plus a last state bootstrapped into from a real,
//!    non-terminal step; padding and terminal observations are never acted from, so
//!    no policy is fitted there. Q_k is the target critic's head for learned
//!    objectives and `-||a_env||_2` for the action norm, with a_env the action the env
//!    executes for the sample (clipped and mapped onto its Box, as the env's reward
//!    sees it), and `-||a - clip(a)||_2` for the out-of-bounds penalty
//!    (`mpo.action_penalization`); weights q_k and the temperature duals (`estep.rs`).
//! 3. **M-step** (eqs. 16-20): weighted maximum likelihood with the decoupled trust
//!    region (`mstep.rs`); one Adam step on the policy and one on all duals, then the
//!    dual floor (`dual.rs`).
//! 4. Every `target_update_period` steps the target networks are copied from the online ones.
//!
//! **ε-conditioned** (`learner.conditioning`, `preferences.rs`): every snippet is trained
//! at one grid point ε_g, drawn for it (relabelling) or the one it was collected with;
//! its states' preference features say which, so policy, critics and Retrace all see
//! (s, ε_g), and the E-step solves eq. 34 per grid point with that point's eta_g.
//! The M-step's trust region (alpha) is shared by all grid points, or with
//! `learner.conditioning.trust_region = "per_point"` kept per grid point (`mstep.rs`).
//!
//! Shape legend: P members, T snippet length, B snippets, N = (T+1)B states (R: the
//! real ones), O observation size, M samples, D action dims, A discrete actions, K
//! objectives, C critics.

use super::batch::{SnippetBatch, StepShape};
use super::estep::{EStepOutput, StateMean, exact_estep_with, sampled_estep_with};
use super::mpo_eval::TargetSamples;
use super::objectives::{QSource, action_norm_q, out_of_bounds_q};
use super::preferences::{StatePreferences, collected_index, relabel};
use super::projection::{Bounds, gaussian_ratios, kl_ratio, project, project_parts};
use super::real_states::{gather_states, real_states};
use super::state::{Learner, LearnerError, LearnerStats, to_vec};
use super::update::{PhaseClock, StepMeasures};
use crate::core::learner_config::GridTrustRegion;
use crate::core::nets::PolicyOutput;
use crate::core::random::Purpose;
use tch::{Kind, Tensor};

/// What the E- and M-steps work on: the states the policy is fitted at, pi_old and
/// its samples there with their Q_k, and how each member averages over the states.
struct Improvement {
    /// `[P, N, O]`.
    obs: Tensor,
    /// pi_old at `obs`.
    target: PolicyOutput,
    /// `[P, M, N, D]` sampled actions, or `[P, A, N]` every action's index.
    actions: Tensor,
    /// `[P, M, N, K]` (`[P, A, N, K]`): Q_k of `actions` (`estep_q`).
    q: Tensor,
    /// `[P, A, N]`: log pi_old of every action (categorical only).
    log_prior: Option<Tensor>,
    /// Each state's grid point (an ε-conditioned learner, one member).
    preferences: Option<StatePreferences>,
    /// `[P, N]`: each member's weight of each state (unconditioned learners).
    state_weight: Tensor,
}

impl Improvement {
    /// How the E-step's duals average over the states: per grid point when
    /// ε-conditioned, else per member.
    fn states(&self) -> StateMean<'_> {
        match &self.preferences {
            Some(p) => StateMean::PerGridPoint(&p.state_weight),
            None => StateMean::Members(&self.state_weight),
        }
    }

    /// How the M-step averages over the states: a conditioned learner's weighted
    /// likelihood (and a shared trust region) averages over all of its states, not
    /// per grid point.
    fn fit_states(&self) -> StateMean<'_> {
        match self.preferences {
            Some(_) => StateMean::Uniform,
            None => self.states(),
        }
    }
}

impl Learner {
    /// Whether an ε-conditioned learner keeps one trust region per grid point.
    fn per_point_trust_region(&self) -> bool {
        self.conditioned
            .as_ref()
            .is_some_and(|c| c.trust_region == GridTrustRegion::PerPoint)
    }

    /// Q-values for the E-step, `[.., M, N, K]`, from critic heads and closed forms.
    fn estep_q(&self, critic_q: &Tensor, actions: &Tensor) -> Tensor {
        let columns: Vec<Tensor> = self
            .bound
            .objectives
            .iter()
            .map(|o| match o.source {
                QSource::Critic { head } => critic_q.select(-1, head as i64),
                QSource::ActionNorm => action_norm_q(actions, self.dims.action_bounds.as_ref()),
                QSource::OutOfBounds => out_of_bounds_q(actions),
            })
            .collect();
        Tensor::stack(&columns, -1)
    }

    /// One MO-MPO step of every member (critic update, E-step, M-step, duals,
    /// target update) on its checked batch; all tensors are member-first.
    pub(super) fn mpo_step(
        &mut self,
        batches: &[SnippetBatch],
    ) -> Result<Vec<LearnerStats>, LearnerError> {
        let mut clock = PhaseClock::start(self.device);
        let (batch, preferences) = self.stack_batches(batches, batches[0].len());
        let shape = StepShape::of(&batch, self.bound.critic_names.len() as i64);
        let obs = batch
            .observations
            .reshape([shape.members, shape.states(), -1]);
        let noise = self.sampling_noise(shape.states())?;

        // 1. Policy evaluation with Retrace (C.2).
        let target = tch::no_grad(|| self.sample_target(obs, noise.as_ref()));
        let critic_loss = self.regress_critics(&batch, &target, shape);
        clock.policy_evaluation_done();

        // 2. E-step (eqs. 32-34), on the real states only (all of them, in most batches).
        let fit = self.at_real_states(&batch, target, preferences);
        let estep = self.estep(&fit);
        clock.e_step_done();

        // 3. M-step (eqs. 16-20) and dual updates, then the trust region's projection.
        let policy_kl = self.fit_improved(&fit, &estep);
        self.project_policy(&fit.obs, &fit.target, fit.fit_states());
        clock.m_step_done();

        // 4. Target networks.
        let value_mean = fit
            .states()
            .over_states(&fit.q.mean_dim(1, false, Kind::Float));
        self.finish_members(StepMeasures {
            critic_loss,
            estep_kl: estep.kl,
            value_mean,
            policy_kl,
            timings: clock.timings(),
        })
    }

    /// The E- and M-steps' inputs at the real states: the states acted from and those
    /// bootstrapped into from a real, non-terminal step. Padding and terminal
    /// observations are never acted from, so no policy is fitted there.
    fn at_real_states(
        &self,
        batch: &SnippetBatch,
        target: TargetSamples,
        preferences: Option<StatePreferences>,
    ) -> Improvement {
        let real = real_states(&batch.valid, &batch.discounts);
        let preferences = match (&real.index, preferences) {
            (Some(index), Some(pr)) => Some(pr.rows(&index.get(0), &self.conditioned_epsilon())),
            (_, preferences) => preferences,
        };
        self.improvement(target, real.index.as_ref(), preferences, real.weight)
    }

    /// The E- and M-steps' inputs at the states of `target`, or, given `rows` (`[P, R]`),
    /// at each member's own rows of them. V is not needed there and not gathered.
    fn improvement(
        &self,
        target: TargetSamples,
        rows: Option<&Tensor>,
        preferences: Option<StatePreferences>,
        state_weight: Tensor,
    ) -> Improvement {
        let at = |t: Tensor, dim: i64| match rows {
            Some(index) => gather_states(&t, index, dim),
            None => t,
        };
        let policy = match rows {
            Some(index) => target.policy.member_rows(index),
            None => target.policy,
        };
        let actions = at(target.actions, 2);
        Improvement {
            q: self.estep_q(&at(target.q, 2), &actions),
            obs: at(target.obs, 1),
            target: policy,
            actions,
            log_prior: target.log_prior.map(|lp| at(lp, 2)),
            preferences,
            state_weight,
        }
    }

    /// The M-step (eqs. 16-20) on the E-step's weights (summed over objectives) and
    /// the temperature duals' loss: one Adam step on the policy and one on all duals.
    /// Returns the policy KL parts before the update, `[P, parts]`.
    fn fit_improved(&mut self, fit: &Improvement, estep: &EStepOutput) -> Tensor {
        let weights = estep.weights.sum_dim_intlist(-1, false, Kind::Float);
        let online = self.nets.policy.forward_members(&fit.obs, None);
        self.fit_policy(
            &online,
            &fit.target,
            &fit.actions,
            &weights,
            &estep.temperature_loss,
            fit.fit_states(),
            fit.preferences
                .as_ref()
                .filter(|_| self.per_point_trust_region()),
        )
    }

    /// The members' batches stacked member-first (on the learner's device), with the
    /// observations as the step trains on them and, for an ε-conditioned learner (one
    /// member), each state's grid point.
    pub(super) fn stack_batches(
        &self,
        batches: &[SnippetBatch],
        t_len: i64,
    ) -> (SnippetBatch, Option<StatePreferences>) {
        let batches: Vec<SnippetBatch> = batches.iter().map(|b| b.to_device(self.device)).collect();
        let (first_obs, preferences) = self.preferences_of(&batches[0].observations, t_len);
        let stack = |field: fn(&SnippetBatch) -> &Tensor| {
            Tensor::stack(&batches.iter().map(field).collect::<Vec<_>>(), 0)
        };
        let observations = match preferences {
            Some(_) => first_obs.unsqueeze(0),
            None => stack(|b| &b.observations),
        };
        (
            SnippetBatch {
                observations,
                actions: stack(|b| &b.actions),
                rewards: stack(|b| &b.rewards),
                discounts: stack(|b| &b.discounts),
                behaviour_log_probs: stack(|b| &b.behaviour_log_probs),
                valid: stack(|b| &b.valid),
            },
            preferences,
        )
    }

    /// Every member's sampling noise of `shape` for this step, `[P, ..shape]`.
    pub(super) fn member_noise(&mut self, shape: &[i64]) -> Result<Tensor, LearnerError> {
        let (device, step) = (self.device, self.step);
        let draws = self
            .noise
            .iter_mut()
            .map(|source| source.standard_normal(shape, device, step))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Tensor::stack(&draws, 0))
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

    /// The E-step on `fit.q [P, M, N, K]` (exact with `fit.log_prior`, categorical),
    /// with each member's ε and eta per objective, or (conditioned, one member) each
    /// state's grid point's.
    fn estep(&self, fit: &Improvement) -> EStepOutput {
        let k = self.bound.objectives.len() as i64;
        let temperature = self.duals.temperature();
        let (temperature, epsilon) = match &fit.preferences {
            None => (
                temperature.reshape([-1, 1, k]),
                self.epsilon.reshape([-1, 1, k]),
            ),
            Some(p) => (
                p.temperature(&temperature.reshape([-1, k])),
                p.epsilon.shallow_clone(),
            ),
        };
        let (q, states) = (&fit.q, fit.states());
        match &fit.log_prior {
            None => sampled_estep_with(q, &temperature, &epsilon, states),
            Some(prior) => exact_estep_with(q, prior, &temperature, &epsilon, states),
        }
    }

    /// Holds each member's policy within `mpo.max_kl_ratio` times its trust region
    /// after the M-step (`projection.rs`), measured as the M-step measures the KL;
    /// keeps the fraction of the step each member kept for the step's statistics.
    fn project_policy(&mut self, obs: &Tensor, target: &PolicyOutput, states: StateMean<'_>) {
        let s = self.settings;
        let Some(max_ratio) = s.max_kl_ratio else {
            return;
        };
        let bounds = Bounds {
            beta_mean: s.beta_mean,
            beta_cov: s.beta_cov,
            beta_categorical: s.beta_categorical,
            constraint: s.kl_constraint,
        };
        let policy = &self.nets.policy;
        let (online, frozen) = (&self.nets.policy_vs, &self.nets.target_policy_vs);
        let kept = match (policy.state_independent_std(), target) {
            (true, PolicyOutput::Gaussian(target)) => {
                project_parts(online, frozen, self.members, max_ratio, || {
                    match policy.forward_members(obs, None) {
                        PolicyOutput::Gaussian(g) => gaussian_ratios(&g, target, &bounds, states),
                        PolicyOutput::Categorical(_) => unreachable!("a Gaussian policy"),
                    }
                })
            }
            _ => project(online, frozen, self.members, max_ratio, || {
                kl_ratio(&policy.forward_members(obs, None), target, &bounds, states)
            }),
        };
        self.policy_step_kept = Some(kept);
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
    /// `q_fn` maps sampled actions `[M, N, D]` to the critic heads' Q `[M, N, C]`;
    /// closed-form objectives (action norm, out-of-bounds penalty) are added as `step`
    /// adds them (`estep_q`), so with learned objectives only C = K. An ε-conditioned
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
        let n = obs.size()[1];
        let target_out = tch::no_grad(|| self.nets.target_policy.forward_members(&obs, None));
        let PolicyOutput::Gaussian(target) = &target_out else {
            panic!("improve_policy_with needs a Gaussian policy");
        };
        let shape = [&[self.cfg.mpo.num_samples][..], &target.mean.size()[1..]].concat();
        let noise = self
            .stream(Purpose::LearnerNoise)
            .normal(&shape, self.device)
            .unsqueeze(0);
        let actions = tch::no_grad(|| target.mean.unsqueeze(1) + noise * target.std.unsqueeze(1));
        let sampled = actions.squeeze_dim(0);
        let q = self.estep_q(&q_fn(&sampled), &sampled).unsqueeze(0);
        let fit = Improvement {
            obs,
            target: target_out,
            actions,
            q,
            log_prior: None,
            preferences,
            state_weight: Tensor::full([1, n], 1.0 / n as f64, (Kind::Float, self.device)),
        };
        let estep = self.estep(&fit);
        let policy_kl = self.fit_improved(&fit, &estep);
        self.advance_targets().expect("same layout");
        (self.duals.values().0, to_vec(&policy_kl))
    }
}
