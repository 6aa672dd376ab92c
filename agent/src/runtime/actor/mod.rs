//! Actors (Algorithm 2): step a remote env session with the latest published
//! policy, record behaviour log-probabilities, and feed T-step snippets to the replay.
//!
//! Shapes: B instances per session, O observation size, D action dims, K objectives.
//! Continuous actions are sampled unclipped (that is what the replay stores and the
//! critic sees); the env receives them clipped to [-1, 1] and mapped linearly onto a
//! finite Box, e.g. [-2, 2] for Pendulum. A session lost to a server restart is
//! made again and the run continues, and so is one whose call missed its deadline
//! (`env.deadlines`: a silent or partitioned server); when its server stays away, the session is made
//! on another server the pool's entries list now ([`ServerPool`]).
//!
//! **Populations**: one actor serves the P members of a population learner with one
//! session of P x B instances, stepped by one call: member p owns instances
//! pB..(p+1)B, seeded as its own run's would be (per-instance reset seeds), acts on
//! them with its own policy and sampling stream, and its snippets, episodes and counts
//! go to its own run (schedule, replay, episodes.csv). Every member gets the same env
//! steps. A member whose run has stopped (solved with `stop_on_solve`) is still
//! stepped, as its instances are part of the session, but records nothing more.
//! On-policy members each get actors of their own (`train::train_population`): their
//! learner allowances follow their own episode ends, and an actor stepping several of
//! them would act for one with a policy its learner step has not yet replaced.
//!
//! **Acting while the learner trains** (off-policy): an actor computes step j + 1
//! (policy forwards and the env call) while the learner takes the steps that step j
//! allowed, then waits for those steps and commits step j + 1 (replay, counts, logs).
//! The learner thus waits for a commit, never for the env, and step j + 1 acts with
//! the policy of the steps allowed before step j: one actor step older than acting
//! after the learner would give (Acme's actors act with policies several learner
//! steps old). Which policy acts at each step and which transitions each learner step
//! can sample stay fixed, so a run still reproduces. On-policy actors act only after
//! the learner's steps: each batch is acted by the policy the previous one produced.

use std::sync::Arc;
use std::time::Instant;

use tch::{Kind, Tensor};
use tokio::sync::watch;

use crate::core::algo::preferences::PreferenceGrid;
use crate::core::nets::{Acting, ActionBounds, ActorPolicy, PolicySnapshot};
use crate::core::random::StreamKey;
use crate::core::replay::SnippetLayout;
use crate::core::spec::Space;
use crate::env::error::EnvError;
use crate::env::pool::{Assignment, ServerPool};
use crate::env::{Env, HostTensor, MakeOptions};
use crate::report::metrics::RunFiles;
use crate::runtime::schedule::{Schedule, wait_for_population_learner};

mod record;
mod session;

use record::record_all;
use session::{Conditioner, Live, Lost, Sessions, restart, start};

/// One member's part of an actor (a single run is a population of one).
#[derive(Debug)]
pub struct ActorMember {
    /// The member's acting policy (parameters arrive through `params`).
    pub policy: ActorPolicy,
    /// The member's sampling stream (`random::Purpose::Acting`, index = actor number);
    /// its counter is the actor's step number.
    pub sampling: StreamKey,
    /// Seed of the member's first instance in the actor's first session (`seed +
    /// 1000 a`); instance j gets `+ j`.
    pub first_seed: u64,
    /// Seeds of sessions made after act 0 (`random::Purpose::EnvSeeds`): a resumed
    /// run's envs continue with new episodes instead of repeating its first ones.
    pub env_seeds: StreamKey,
    /// Latest published policy parameters.
    pub params: watch::Receiver<Arc<PolicySnapshot>>,
    /// The member's rate limiter and replay.
    pub schedule: Arc<Schedule>,
    /// The member's episode log.
    pub files: Arc<RunFiles>,
    /// ε-conditioned runs: the grid every episode draws its preference from, and the
    /// actor's stream for those draws (`random::Purpose::ActingPreference`).
    pub preferences: Option<(Arc<PreferenceGrid>, StreamKey)>,
}

/// What one actor needs.
#[derive(Debug)]
pub struct ActorContext {
    /// Actor number (seeds and logs).
    pub id: usize,
    /// The server the actor starts on.
    pub server: Assignment,
    /// The run's servers, asked for another when this actor's server is lost.
    pub servers: Arc<ServerPool>,
    /// Session to make (and to make again after a server restart), with B instances
    /// per member (`num_envs`); the session has P B.
    pub make: MakeOptions,
    /// The members, in order.
    pub members: Vec<ActorMember>,
    /// Act calls already made (a resumed run's count, else 0).
    pub first_act: u64,
    /// Snippet sizes of the replay.
    pub layout: SnippetLayout,
    /// Stop after this many env steps per member.
    pub total_env_steps: u64,
}

/// Maps policy actions to env actions: continuous ones clipped to [-1, 1] and mapped
/// linearly onto a finite Box (`ActionBounds::to_env`), discrete indices offset by the
/// space's start.
#[derive(Debug, Clone)]
pub enum ActionMap {
    /// Box bounds per element (`[D]`).
    Continuous(ActionBounds),
    /// First index of the Discrete space.
    #[allow(missing_docs, reason = "named by its field")]
    Discrete { start: i64 },
}

impl ActionMap {
    /// The map for an env action space (Dict spaces are not supported).
    pub fn new(space: &Space) -> Result<Self, EnvError> {
        match space {
            Space::Box(b) => Ok(ActionMap::Continuous(ActionBounds {
                low: b.low.iter().map(|&v| v as f32).collect(),
                high: b.high.iter().map(|&v| v as f32).collect(),
            })),
            Space::Discrete(d) => Ok(ActionMap::Discrete { start: d.start }),
            Space::Dict(_) => Err(EnvError::BadInput {
                field: "action_space".into(),
                expected: "Box or Discrete".into(),
                got: "Dict".into(),
            }),
        }
    }

    /// Env action tensor `[B, ...]` and the replay's action rows (`[B, D]` unclipped
    /// samples, or `[B]` indices).
    pub fn apply(&self, actions: &Tensor, b: usize) -> (HostTensor, Vec<f32>) {
        match self {
            ActionMap::Continuous(bounds) => {
                let actions = actions.to_kind(Kind::Float);
                let raw = Vec::<f32>::try_from(&actions.flatten(0, -1)).expect("f32 actions");
                let env = Vec::<f32>::try_from(&bounds.to_env(&actions).flatten(0, -1))
                    .expect("f32 actions");
                (HostTensor::from_f32(vec![b, bounds.low.len()], &env), raw)
            }
            ActionMap::Discrete { start } => {
                let idx = Vec::<i64>::try_from(&actions.to_kind(Kind::Int64).flatten(0, -1))
                    .expect("i64 actions");
                let env: Vec<i64> = idx.iter().map(|a| a + start).collect();
                (
                    HostTensor::from_i64(vec![b], &env),
                    idx.iter().map(|&a| a as f32).collect(),
                )
            }
        }
    }
}

/// Where in the run a step is: the actor, its act count, B and the snippet sizes.
#[derive(Clone, Copy)]
struct StepAt {
    actor: usize,
    acts: u64,
    b: usize,
    layout: SnippetLayout,
}

/// What every member's policy did at one step: the env's action for the whole
/// session, and the replay's actions and behaviour log-probabilities, member after
/// member (`[P B, D]` or `[P B]`, and `[P B]`).
struct Acted {
    env_action: HostTensor,
    replay_actions: Vec<f32>,
    log_probs: Vec<f32>,
}

/// Every member's policy on its instances' observations, sampled from its stream at
/// act `acts`.
fn act_all(members: &[ActorMember], live: &Live, map: &ActionMap, at: StepAt) -> Acted {
    let (b, o) = (at.b as i64, at.layout.obs_dim as i64);
    let (mut actions, mut log_probs) = (Vec::new(), Vec::new());
    for (m, obs) in members.iter().zip(&live.obs) {
        let obs_t = Tensor::from_slice(obs).view([b, o]);
        let out = m
            .policy
            .act(&obs_t, Acting::Sample(&mut m.sampling.at(at.acts)));
        actions.push(out.actions);
        log_probs.push(out.log_probs.to_kind(Kind::Float));
    }
    let log_probs = Vec::<f32>::try_from(&Tensor::cat(&log_probs, 0)).expect("f32 log-probs");
    let (env_action, replay_actions) = map.apply(&Tensor::cat(&actions, 0), at.b * members.len());
    Acted {
        env_action,
        replay_actions,
        log_probs,
    }
}

/// Waits until the learner has taken every step the committed env steps allow (the
/// member allowing the fewest), then loads each member's policy published by then.
async fn catch_up(schedules: &[&Schedule], members: &mut [ActorMember]) -> Result<(), EnvError> {
    wait_for_population_learner(schedules).await;
    for m in members {
        if m.params.has_changed().unwrap_or(false) {
            let snapshot = m.params.borrow_and_update().clone();
            m.policy
                .load(&snapshot)
                .map_err(|e| EnvError::Process(format!("policy snapshot: {e}")))?;
        }
    }
    Ok(())
}

/// Each ε-conditioned member's preference state for its B instances.
fn conditioners(members: &[ActorMember], b: usize) -> Vec<Option<Conditioner>> {
    members
        .iter()
        .map(|m| {
            m.preferences.clone().map(|(grid, draws)| Conditioner {
                grid,
                draws,
                current: vec![0; b],
            })
        })
        .collect()
}

/// The actor's first session, on its assigned server or, when that server went away
/// between the pool's connect and this session, wherever `restart` finds one; `None`
/// when the run ended while it looked.
async fn first_session(
    sessions: &Sessions<'_>,
    on: &mut Assignment,
    conds: &mut [Option<Conditioner>],
    acts: u64,
) -> Result<Option<Live>, EnvError> {
    let began = Instant::now();
    match start(sessions, &on.client, conds, acts).await {
        Ok(live) => Ok(Some(live)),
        Err(e) if e.lost_session() => {
            let lost = Lost {
                cause: &e,
                since: began,
            };
            restart(sessions, on, lost, conds, acts).await
        }
        Err(e) => Err(e),
    }
}

/// What one env call came to.
enum Stepped {
    /// The step's result.
    Step(crate::env::StepResult),
    /// The session was lost and made again (this act is not recorded).
    Restarted,
    /// The session was lost and the run ended while the actor looked for a server.
    Ended,
}

/// Steps the session with `acted`'s actions; a lost session is made again in `live`.
async fn step_session(
    sessions: &Sessions<'_>,
    on: &mut Assignment,
    conds: &mut [Option<Conditioner>],
    live: &mut Live,
    acted: &Acted,
    acts: u64,
) -> Result<Stepped, EnvError> {
    let called = Instant::now();
    match live.env.step(&acted.env_action).await {
        Ok(step) => Ok(Stepped::Step(step)),
        Err(e) if e.lost_session() => {
            let lost = Lost {
                cause: &e,
                since: called,
            };
            match restart(sessions, on, lost, conds, acts).await? {
                Some(restarted) => {
                    *live = restarted;
                    Ok(Stepped::Restarted)
                }
                None => Ok(Stepped::Ended),
            }
        }
        Err(e) => Err(e),
    }
}

/// Run until every member's env-step budget is spent or its run stops.
pub async fn run_actor(ctx: ActorContext) -> Result<(), EnvError> {
    let ActorContext {
        id,
        server,
        servers,
        make,
        mut members,
        first_act,
        layout,
        total_env_steps,
    } = ctx;
    let b = make.num_envs;
    let schedules: Vec<Arc<Schedule>> = members.iter().map(|m| m.schedule.clone()).collect();
    let sessions = Sessions {
        id,
        servers: &servers,
        make: &make,
        seeds: members
            .iter()
            .map(|m| (m.first_seed, m.env_seeds))
            .collect(),
        layout,
        schedules: schedules.iter().map(Arc::as_ref).collect(),
        total_env_steps,
    };
    // Off-policy, an actor steps its envs while the learner takes the steps that its
    // previous step allowed, and commits the new step once they are taken (module
    // docs); on-policy, each step acts with the policy of every step allowed so far.
    let pipelined = !layout.on_policy;
    let mut conds = conditioners(&members, b);
    let mut on = server;
    let mut acts = first_act;
    let Some(mut live) = first_session(&sessions, &mut on, &mut conds, acts).await? else {
        return Ok(());
    };
    // Every way out of the loop, an error included, closes the session: a server
    // would otherwise hold it (and its simulators) until its lease runs out.
    let result: Result<(), EnvError> = async {
        let map = ActionMap::new(&live.env.spec().action_space)?;
        // Waiting before the first act makes a resumed actor wait, as the stopped
        // one was waiting, for the learner steps its checkpoint allowed.
        catch_up(&sessions.schedules, &mut members).await?;
        loop {
            if sessions.ended() {
                // The run ends once the learner has taken the steps the last commit
                // allowed (at once when acting after the learner: its wait did this).
                wait_for_population_learner(&sessions.schedules).await;
                break;
            }
            let at = StepAt {
                actor: id,
                acts,
                b,
                layout,
            };
            let acted = act_all(&members, &live, &map, at);
            acts += 1;
            let at = StepAt { acts, ..at };
            let step = match step_session(&sessions, &mut on, &mut conds, &mut live, &acted, acts)
                .await?
            {
                Stepped::Step(step) => step,
                Stepped::Restarted => continue,
                Stepped::Ended => break,
            };
            if pipelined {
                catch_up(&sessions.schedules, &mut members).await?;
            }
            record_all(&members, &mut conds, &mut live, &step, &acted, at)?;
            if !pipelined {
                catch_up(&sessions.schedules, &mut members).await?;
            }
        }
        Ok(())
    }
    .await;
    // The session may already be gone if the server went away at the very end.
    let _ = live.env.close().await;
    result
}
