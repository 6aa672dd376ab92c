//! Actors (Algorithm 2): step a remote env session with the latest published
//! policy, record behaviour log-probabilities, and feed T-step snippets to the replay.
//!
//! Shapes: B instances per session, O observation size, D action dims, K objectives.
//! Continuous actions are sampled unclipped (that is what the replay stores and the
//! critic sees); the env receives them clipped to [-1, 1] and mapped linearly onto a
//! finite Box, e.g. [-2, 2] for Pendulum. A session lost to a server restart is
//! made again and the run continues; when its server stays away, the session is made
//! on another server the pool's entries list now ([`ServerPool`]).

use std::sync::Arc;
use std::time::Duration;

use tch::{Kind, Tensor};
use tokio::sync::watch;

use crate::algo::preferences::PreferenceGrid;
use crate::env::grpc::{EnvClient, RemoteEnv, RetryPolicy};
use crate::env::pool::{Assignment, ServerPool};
use crate::env::{Env, HostTensor, MakeOptions};
use crate::error::{EnvError, StatusKind};
use crate::metrics::{EpisodeRecord, RunFiles};
use crate::nets::{Acting, ActionBounds, ActorPolicy, PolicySnapshot};
use crate::random::StreamKey;
use crate::replay::SnippetLayout;
use crate::replay::adder::{AdderStep, SnippetAdder};
use crate::schedule::{ActorStep, Schedule};
use crate::spec::Space;

/// What one actor needs.
#[derive(Debug)]
pub struct ActorContext {
    /// Actor number (seeds and logs).
    pub id: usize,
    /// The server the actor starts on.
    pub server: Assignment,
    /// The run's servers, asked for another when this actor's server is lost.
    pub servers: Arc<ServerPool>,
    /// Session to make (and to make again after a server restart).
    pub make: MakeOptions,
    /// The acting policy (parameters arrive through `params`).
    pub policy: ActorPolicy,
    /// The actor's sampling stream (`random::Purpose::Acting`, index = actor number);
    /// its counter is the actor's step number.
    pub sampling: StreamKey,
    /// Act calls already made (a resumed run's count, else 0).
    pub first_act: u64,
    /// Seeds of sessions made after act 0 (`random::Purpose::EnvSeeds`): a resumed
    /// run's envs continue with new episodes instead of repeating its first ones.
    pub env_seeds: StreamKey,
    /// Latest published policy parameters.
    pub params: watch::Receiver<Arc<PolicySnapshot>>,
    /// Snippet sizes of the replay.
    pub layout: SnippetLayout,
    /// Rate limiter and replay.
    pub schedule: Arc<Schedule>,
    /// Episode log.
    pub files: Arc<RunFiles>,
    /// Stop after this many env steps in total.
    pub total_env_steps: u64,
    /// ε-conditioned runs: the grid every episode draws its preference from, and the
    /// actor's stream for those draws (`random::Purpose::ActingPreference`).
    pub preferences: Option<(Arc<PreferenceGrid>, StreamKey)>,
}

/// The preference each instance of an ε-conditioned actor acts with in its current
/// episode; observations are passed on (to the policy and the replay) with that
/// preference's features appended.
struct Conditioner {
    grid: Arc<PreferenceGrid>,
    draws: StreamKey,
    /// Grid point of each instance's current episode.
    current: Vec<usize>,
}

impl Conditioner {
    /// New preferences for every instance (a new session); stream counter
    /// `2 * acts + 1`, apart from the per-step draws' `2 * acts`.
    fn redraw_all(&mut self, acts: u64) {
        let mut stream = self.draws.at(2 * acts + 1);
        for g in &mut self.current {
            *g = self.grid.draw(&mut stream);
        }
    }
}

/// Env observation rows `[R, O_env]` as the policy and the replay see them: unchanged,
/// or with the features of `rows`' preferences appended (`None`: every instance's).
fn observed(cond: &Option<Conditioner>, obs: Vec<f32>, rows: Option<&[usize]>) -> Vec<f32> {
    match cond {
        // No rows (e.g. no final observations this step) stay no rows.
        None => obs,
        Some(_) if obs.is_empty() => obs,
        Some(c) => {
            let prefs: Vec<usize> = match rows {
                None => c.current.clone(),
                Some(rows) => rows.iter().map(|&i| c.current[i]).collect(),
            };
            let width = obs.len().checked_div(prefs.len()).unwrap_or(0);
            c.grid.append(&obs, width, &prefs)
        }
    }
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

/// A live session with its per-instance adders and the current observations.
struct Live {
    env: RemoteEnv,
    adders: Vec<SnippetAdder>,
    obs: Vec<f32>,
}

/// The parts of an actor that make sessions (shared across awaits, so no tensors).
struct Sessions<'a> {
    id: usize,
    servers: &'a ServerPool,
    make: &'a MakeOptions,
    layout: SnippetLayout,
    schedule: &'a Schedule,
    total_env_steps: u64,
    env_seeds: StreamKey,
}

/// The session's options at act `acts`: the run's seeds at its start, then seeds
/// drawn from the actor's `EnvSeeds` stream at the act count.
fn session_options(ctx: &Sessions<'_>, acts: u64) -> MakeOptions {
    let mut make = ctx.make.clone();
    if acts > 0 {
        make.seed = Some(ctx.env_seeds.seed_at(acts));
    }
    make
}

async fn start(
    ctx: &Sessions<'_>,
    client: &EnvClient,
    cond: &mut Option<Conditioner>,
    acts: u64,
) -> Result<Live, EnvError> {
    let mut env = client.make(&session_options(ctx, acts)).await?;
    // One stream per session: about 0.2 ms less per step than unary calls (issue 2's
    // bench). A broken stream closes the session on the server; `restart` makes it again.
    env.use_stream();
    let reset = env.reset(&[], &[]).await?;
    if let Some(c) = cond.as_mut() {
        c.redraw_all(acts);
    }
    let obs = observed(cond, reset.observation.to_flat_f32(), None);
    let o = ctx.layout.obs_dim;
    let mut adders = vec![SnippetAdder::new(ctx.layout); ctx.make.num_envs];
    for (i, adder) in adders.iter_mut().enumerate() {
        adder.observe_first(&obs[i * o..(i + 1) * o]);
    }
    Ok(Live { env, adders, obs })
}

/// Make the session again after it was lost: on the same server when it answers again
/// (a restart), else on another address the pool resolves now, backing off between
/// rounds over all of them; it gives up after about 5 minutes in which no server took
/// the session. `None`: the run ended meanwhile.
async fn restart(
    ctx: &Sessions<'_>,
    on: &mut Assignment,
    cause: &EnvError,
    cond: &mut Option<Conditioner>,
    acts: u64,
) -> Result<Option<Live>, EnvError> {
    tracing::warn!(actor = ctx.id, server = %on.address, error = %cause, "env session lost; reconnecting");
    let mut delay = Duration::from_millis(200);
    let mut last = None;
    // Backoff 0.2 s doubling to 5 s: about 5 minutes over 64 rounds, enough for a
    // server (or its replacement) to start.
    for _ in 0..64 {
        let c = ctx.schedule.counters();
        if c.stop || c.env_steps >= ctx.total_env_steps {
            return Ok(None);
        }
        for address in ctx.servers.candidates(&on.address).await {
            let attempt = match ctx.servers.client(&address).await {
                // Probed with few retries: other addresses wait, and rounds back off.
                Ok(client) => start(ctx, &client.with_retry(RetryPolicy::quick()), cond, acts)
                    .await
                    .map(|live| (live, client)),
                Err(e) => Err(e),
            };
            match attempt {
                Ok((live, client)) => {
                    if address == on.address {
                        tracing::info!(actor = ctx.id, server = %address, "env session made again");
                    } else {
                        ctx.servers.moved(ctx.id, &on.address, &address);
                    }
                    *on = Assignment { address, client };
                    return Ok(Some(live));
                }
                Err(e) if recoverable(&e) => {
                    if unreachable(&e) {
                        ctx.servers.forget(&address);
                    }
                    tracing::warn!(actor = ctx.id, server = %address, error = %e, "reconnect failed");
                    last = Some(e);
                }
                Err(e) => return Err(e),
            }
        }
        tokio::time::sleep(delay).await;
        delay = (delay * 2).min(Duration::from_secs(5));
    }
    let last = last.map_or_else(String::new, |e| format!(" (last attempt: {e})"));
    Err(EnvError::Process(format!(
        "actor {}: could not make the session again after: {cause}{last}",
        ctx.id
    )))
}

/// The server did not answer at all (as opposed to answering NOT_FOUND).
fn unreachable(e: &EnvError) -> bool {
    e.status_kind() == Some(StatusKind::Unavailable) || matches!(e, EnvError::Connect { .. })
}

fn recoverable(e: &EnvError) -> bool {
    matches!(
        e.status_kind(),
        Some(StatusKind::Unavailable | StatusKind::NotFound)
    ) || matches!(e, EnvError::Connect { .. })
}

/// Run until the env-step budget is spent or the schedule stops.
pub async fn run_actor(ctx: ActorContext) -> Result<(), EnvError> {
    let ActorContext {
        id,
        server,
        servers,
        make,
        mut policy,
        sampling,
        first_act,
        env_seeds,
        mut params,
        layout,
        schedule,
        files,
        total_env_steps,
        preferences,
    } = ctx;
    let sessions = Sessions {
        id,
        servers: &servers,
        make: &make,
        layout,
        schedule: &schedule,
        total_env_steps,
        env_seeds,
    };
    let b = make.num_envs;
    let (o, k) = (layout.obs_dim, layout.num_rewards);
    let mut cond = preferences.map(|(grid, draws)| Conditioner {
        grid,
        draws,
        current: vec![0; b],
    });
    let mut on = server;
    let mut acts = first_act;
    let mut live = match start(&sessions, &on.client, &mut cond, acts).await {
        Ok(live) => live,
        // The server went away between the pool's connect and this session.
        Err(e) if recoverable(&e) => {
            match restart(&sessions, &mut on, &e, &mut cond, acts).await? {
                Some(live) => live,
                None => return Ok(()),
            }
        }
        Err(e) => return Err(e),
    };
    // Every way out of the loop, an error included, closes the session: a server
    // would otherwise hold it (and its simulators) until its lease runs out.
    let result: Result<(), EnvError> = async {
        let map = ActionMap::new(&live.env.spec().action_space)?;
        loop {
            // Waiting before acting (not after) makes a resumed actor wait, as the
            // stopped one was waiting, for the learner steps its checkpoint allowed.
            schedule.wait_for_learner().await;
            if params.has_changed().unwrap_or(false) {
                let snapshot = params.borrow_and_update().clone();
                policy
                    .load(&snapshot)
                    .map_err(|e| EnvError::Process(format!("policy snapshot: {e}")))?;
            }
            let c = schedule.counters();
            if c.stop || c.env_steps >= total_env_steps {
                break;
            }
            let obs_t = Tensor::from_slice(&live.obs).view([b as i64, o as i64]);
            let mut stream = sampling.at(acts);
            acts += 1;
            let out = policy.act(&obs_t, Acting::Sample(&mut stream));
            let log_probs =
                Vec::<f32>::try_from(&out.log_probs.to_kind(Kind::Float)).expect("f32 log-probs");
            let (env_action, replay_actions) = map.apply(&out.actions, b);
            let step = match live.env.step(&env_action).await {
                Ok(step) => step,
                Err(e) if recoverable(&e) => {
                    match restart(&sessions, &mut on, &e, &mut cond, acts).await? {
                        Some(restarted) => {
                            live = restarted;
                            continue;
                        }
                        None => break,
                    }
                }
                Err(e) => return Err(e),
            };
            let next_env = step.observation.to_flat_f32();
            // Both with the preference of the episode that just stepped.
            let next = observed(&cond, next_env.clone(), None);
            let ended: Vec<usize> = step.episodes.iter().map(|e| e.env_index).collect();
            let finals = observed(&cond, step.final_observation.to_flat_f32(), Some(&ended));
            let mut draws = cond.as_ref().map(|c| c.draws.at(2 * acts));
            // The grid point each ended episode acted with, before new ones are drawn.
            let ended_with: Vec<usize> = ended
                .iter()
                .map(|&i| cond.as_ref().map_or(0, |c| c.current[i]))
                .collect();
            let width = replay_actions.len() / b;
            let mut snippets = Vec::new();
            for i in 0..b {
                let ended_at = step.episodes.iter().position(|e| e.env_index == i);
                let next_obs = match ended_at {
                    Some(j) if !finals.is_empty() => &finals[j * o..(j + 1) * o],
                    _ => &next[i * o..(i + 1) * o],
                };
                let adder_step = AdderStep {
                    action: &replay_actions[i * width..(i + 1) * width],
                    reward: &step.reward[i * k..(i + 1) * k],
                    next_observation: next_obs,
                    terminated: step.terminated[i],
                    truncated: step.truncated[i],
                    log_prob: log_probs[i],
                };
                snippets.extend(live.adders[i].add(adder_step));
                if ended_at.is_some() {
                    // The next episode acts with a new preference from its first state.
                    if let (Some(c), Some(stream)) = (cond.as_mut(), draws.as_mut()) {
                        c.current[i] = c.grid.draw(stream);
                    }
                    let first = match &cond {
                        Some(c) => {
                            let w = o - c.grid.num_features();
                            observed(&cond, next_env[i * w..(i + 1) * w].to_vec(), Some(&[i]))
                        }
                        None => next[i * o..(i + 1) * o].to_vec(),
                    };
                    live.adders[i].observe_first(&first);
                }
            }
            live.obs = match cond {
                Some(_) => observed(&cond, next_env, None),
                None => next,
            };
            let returns = step.episodes.iter().map(|e| e.episode_return.clone());
            let actor_step = ActorStep {
                actor: id,
                acts,
                env_steps: b as u64,
                snippets,
                episode_returns: returns.collect(),
            };
            let wall_seconds = schedule.elapsed_seconds();
            let log = |env_steps: u64| {
                step.episodes
                    .iter()
                    .zip(&ended_with)
                    .try_for_each(|(episode, &g)| {
                        files.episode(&EpisodeRecord {
                            env_steps,
                            actor: id,
                            episode: episode.clone(),
                            wall_seconds,
                            preference: cond
                                .as_ref()
                                .map_or_else(Vec::new, |c| c.grid.conditioned_epsilon(g)),
                        })
                    })
            };
            schedule
                .commit(actor_step, log)
                .map_err(|e| EnvError::Process(e.to_string()))?;
        }
        Ok(())
    }
    .await;
    // The session may already be gone if the server went away at the very end.
    let _ = live.env.close().await;
    result
}
