//! Recording a step: each member's part of the session's step (its instances' rows)
//! becomes its snippets (the adders cut them), its episode log rows and its counts,
//! committed to its run's schedule. An episode that ended starts the next one, with a
//! new preference when the member is ε-conditioned.
//!
//! Shapes: P members, B instances per member, O observation size, K objectives.

use super::session::{Conditioner, Live, observed};
use super::{Acted, ActorMember, StepAt};
use crate::core::replay::Snippet;
use crate::core::replay::adder::AdderStep;
use crate::env::error::EnvError;
use crate::report::metrics::EpisodeRecord;
use crate::runtime::schedule::ActorStep;

/// What one env step gave one member: its instances' rows, local indices.
struct MemberStep<'a> {
    /// The member's number.
    p: usize,
    /// Its next observations as the env gives them `[B, O_env]`.
    next_env: Vec<f32>,
    /// Its episodes that ended, with instance indices local to the member.
    episodes: Vec<crate::env::EpisodeSummary>,
    /// Their final observations `[E, O_env]`.
    finals: Vec<f32>,
    /// The whole step (rewards and flags are read at the member's rows).
    step: &'a crate::env::StepResult,
}

/// Records each member's part of `step` in its run; a member whose run has ended only
/// keeps its instances' observations (the session still steps them).
pub(super) fn record_all(
    members: &[ActorMember],
    conds: &mut [Option<Conditioner>],
    live: &mut Live,
    step: &crate::env::StepResult,
    acted: &Acted,
    at: StepAt,
) -> Result<(), EnvError> {
    for (p, (m, cond)) in members.iter().zip(conds.iter_mut()).enumerate() {
        let ms = split_step(step, p, at.b);
        if m.schedule.stopping() {
            live.obs[p] = observed(cond, ms.next_env, None);
            continue;
        }
        record_member(m, cond, live, ms, acted.member(p, at.b, members.len()), at)?;
    }
    Ok(())
}

impl Acted {
    /// Member `p`'s rows of the replay's actions and log-probabilities.
    fn member(&self, p: usize, b: usize, members: usize) -> MemberActs<'_> {
        let width = self.replay_actions.len() / (b * members);
        let rows = p * b..(p + 1) * b;
        MemberActs {
            replay_actions: &self.replay_actions[rows.start * width..rows.end * width],
            log_probs: &self.log_probs[rows],
        }
    }
}

/// One member's rows of what the policies did (see [`Acted`]).
#[derive(Clone, Copy)]
struct MemberActs<'a> {
    replay_actions: &'a [f32],
    log_probs: &'a [f32],
}

/// Turns one member's part of a step into its snippets and episode log rows, and
/// commits them to its run.
fn record_member(
    member: &ActorMember,
    cond: &mut Option<Conditioner>,
    live: &mut Live,
    ms: MemberStep<'_>,
    acted: MemberActs<'_>,
    at: StepAt,
) -> Result<(), EnvError> {
    // The grid point each ended episode acted with, before new ones are drawn.
    let ended_with: Vec<usize> = ms
        .episodes
        .iter()
        .map(|e| cond.as_ref().map_or(0, |c| c.current[e.env_index]))
        .collect();
    let snippets = add_snippets(cond, live, &ms, acted, at);
    let returns = ms.episodes.iter().map(|e| e.episode_return.clone());
    let actor_step = ActorStep {
        actor: at.actor,
        acts: at.acts,
        env_steps: at.b as u64,
        snippets,
        episode_returns: returns.collect(),
    };
    let wall_seconds = member.schedule.elapsed_seconds();
    let log = |env_steps: u64| {
        ms.episodes
            .iter()
            .zip(&ended_with)
            .try_for_each(|(episode, &g)| {
                member.files.episode(&EpisodeRecord {
                    env_steps,
                    actor: at.actor,
                    episode: episode.clone(),
                    wall_seconds,
                    preference: cond
                        .as_ref()
                        .map_or_else(Vec::new, |c| c.grid.conditioned_epsilon(g)),
                })
            })
    };
    member
        .schedule
        .commit(actor_step, log)
        .map_err(|e| EnvError::Process(e.to_string()))
}

/// Feeds each of the member's instances' transitions to its adder; an instance whose
/// episode ended starts the next one (with a new preference, when conditioned). Its
/// snippets, and the member's observations for the next act.
fn add_snippets(
    cond: &mut Option<Conditioner>,
    live: &mut Live,
    ms: &MemberStep<'_>,
    acted: MemberActs<'_>,
    at: StepAt,
) -> Vec<Snippet> {
    let StepAt {
        acts, b, layout, ..
    } = at;
    let (o, k) = (layout.obs_dim, layout.num_rewards);
    let offset = ms.p * b;
    let next = observed(cond, ms.next_env.clone(), None);
    let ended: Vec<usize> = ms.episodes.iter().map(|e| e.env_index).collect();
    let finals = observed(cond, ms.finals.clone(), Some(&ended));
    let mut draws = cond.as_ref().map(|c| c.draws.at(2 * acts));
    let width = acted.replay_actions.len() / b;
    let mut snippets = Vec::new();
    for i in 0..b {
        let g = offset + i;
        let ended_at = ended.iter().position(|&e| e == i);
        let next_obs = match ended_at {
            Some(j) if !finals.is_empty() => &finals[j * o..(j + 1) * o],
            _ => &next[i * o..(i + 1) * o],
        };
        let adder_step = AdderStep {
            action: &acted.replay_actions[i * width..(i + 1) * width],
            reward: &ms.step.reward[g * k..(g + 1) * k],
            next_observation: next_obs,
            terminated: ms.step.terminated[g],
            truncated: ms.step.truncated[g],
            log_prob: acted.log_probs[i],
        };
        snippets.extend(live.adders[g].add(adder_step));
        if ended_at.is_some() {
            // The next episode acts with a new preference from its first state.
            if let (Some(c), Some(stream)) = (cond.as_mut(), draws.as_mut()) {
                c.current[i] = c.grid.draw(stream);
            }
            let first = match cond {
                Some(c) => {
                    let w = o - c.grid.num_features();
                    observed(cond, ms.next_env[i * w..(i + 1) * w].to_vec(), Some(&[i]))
                }
                None => next[i * o..(i + 1) * o].to_vec(),
            };
            live.adders[g].observe_first(&first);
        }
    }
    live.obs[ms.p] = match cond {
        Some(_) => observed(cond, ms.next_env.clone(), None),
        None => next,
    };
    snippets
}

/// Each member's part of a step's ended episodes and final observations.
fn split_step(step: &crate::env::StepResult, p: usize, b: usize) -> MemberStep<'_> {
    let all = step.observation.to_flat_f32();
    let width = all.len() / step.terminated.len().max(1);
    let finals_all = step.final_observation.to_flat_f32();
    let final_width = finals_all.len() / step.episodes.len().max(1);
    let mut episodes = Vec::new();
    let mut finals = Vec::new();
    for (j, e) in step.episodes.iter().enumerate() {
        if e.env_index / b == p {
            episodes.push(crate::env::EpisodeSummary {
                env_index: e.env_index - p * b,
                ..e.clone()
            });
            finals.extend_from_slice(&finals_all[j * final_width..(j + 1) * final_width]);
        }
    }
    MemberStep {
        p,
        next_env: all[p * b * width..(p + 1) * b * width].to_vec(),
        episodes,
        finals,
        step,
    }
}
