//! An actor's env session: making it (P x B instances with each member's seeds),
//! making it again after its server is lost (on the same server or another the pool
//! resolves), and the preference each instance of an ε-conditioned member acts with.
//!
//! Shapes: P members, B instances per member, O observation size.

use std::sync::Arc;
use std::time::Instant;

use crate::core::algo::preferences::PreferenceGrid;
use crate::core::random::StreamKey;
use crate::core::replay::SnippetLayout;
use crate::core::replay::adder::SnippetAdder;
use crate::env::deadline::Backoff;
use crate::env::discovery::ServerAddress;
use crate::env::error::EnvError;
use crate::env::grpc::{EnvClient, RemoteEnv, RetryPolicy};
use crate::env::pool::{Assignment, ServerPool};
use crate::env::{Env, MakeOptions};
use crate::runtime::schedule::Schedule;

/// The preference each instance of an ε-conditioned actor acts with in its current
/// episode; observations are passed on (to the policy and the replay) with that
/// preference's features appended.
pub(super) struct Conditioner {
    pub(super) grid: Arc<PreferenceGrid>,
    pub(super) draws: StreamKey,
    /// Grid point of each instance's current episode.
    pub(super) current: Vec<usize>,
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
pub(super) fn observed(
    cond: &Option<Conditioner>,
    obs: Vec<f32>,
    rows: Option<&[usize]>,
) -> Vec<f32> {
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

/// A live session with its per-instance adders (P B, member by member) and each
/// member's current observations (as its policy sees them).
pub(super) struct Live {
    pub(super) env: RemoteEnv,
    pub(super) adders: Vec<SnippetAdder>,
    pub(super) obs: Vec<Vec<f32>>,
}

/// The parts of an actor that make sessions (shared across awaits, so no tensors).
pub(super) struct Sessions<'a> {
    pub(super) id: usize,
    pub(super) servers: &'a ServerPool,
    pub(super) make: &'a MakeOptions,
    /// Each member's first seed and later-session seed stream.
    pub(super) seeds: Vec<(u64, StreamKey)>,
    pub(super) layout: SnippetLayout,
    pub(super) schedules: Vec<&'a Schedule>,
    pub(super) total_env_steps: u64,
}

impl Sessions<'_> {
    /// Every instance's seed for a session made at act `acts`: member p's run's seeds
    /// at its start, then seeds drawn from its `EnvSeeds` stream at the act count.
    fn instance_seeds(&self, acts: u64) -> Vec<u64> {
        let b = self.make.num_envs as u64;
        self.seeds
            .iter()
            .flat_map(|&(first, stream)| {
                let base = if acts == 0 {
                    first
                } else {
                    stream.seed_at(acts)
                };
                (0..b).map(move |j| base + j)
            })
            .collect()
    }

    /// The run has ended for every member (stopped, or the budget spent).
    pub(super) fn ended(&self) -> bool {
        self.schedules.iter().all(|s| {
            let c = s.counters();
            c.stop || c.env_steps >= self.total_env_steps
        })
    }
}

pub(super) async fn start(
    ctx: &Sessions<'_>,
    client: &EnvClient,
    conds: &mut [Option<Conditioner>],
    acts: u64,
) -> Result<Live, EnvError> {
    let seeds = ctx.instance_seeds(acts);
    let mut make = ctx.make.clone();
    make.num_envs = seeds.len();
    make.seed = seeds.first().copied();
    let mut env = client.make(&make).await?;
    // One stream per session: about 0.2 ms less per step than unary calls (issue 2's
    // bench). A broken stream closes the session on the server; `restart` makes it again.
    env.use_stream();
    let reset = env.reset(&[], &seeds).await?;
    let all = reset.observation.to_flat_f32();
    let (b, o) = (ctx.make.num_envs, ctx.layout.obs_dim);
    let width = all.len() / seeds.len().max(1);
    let mut adders = vec![SnippetAdder::new(ctx.layout); seeds.len()];
    let mut obs = Vec::with_capacity(conds.len());
    for (p, cond) in conds.iter_mut().enumerate() {
        if let Some(c) = cond.as_mut() {
            c.redraw_all(acts);
        }
        let member = observed(cond, all[p * b * width..(p + 1) * b * width].to_vec(), None);
        for (i, adder) in adders[p * b..(p + 1) * b].iter_mut().enumerate() {
            adder.observe_first(&member[i * o..(i + 1) * o]);
        }
        obs.push(member);
    }
    Ok(Live { env, adders, obs })
}

/// Make the session again after it was lost (`since`: when the call that failed
/// began): on the same server when it answers again (a restart), else on another
/// address the pool resolves now, backing off between rounds over all of them; it
/// gives up after `env.deadlines.reconnect_seconds` in which no server took the
/// session. A server that missed a deadline is tried last in the first round, so its
/// actors move within one deadline when another server answers. `None`: the run
/// ended meanwhile.
/// Why a session is made again: the error that lost it, and since when it has been
/// trying (how long it may keep trying is counted from then).
pub(super) struct Lost<'a> {
    pub cause: &'a EnvError,
    pub since: Instant,
}

pub(super) async fn restart(
    ctx: &Sessions<'_>,
    on: &mut Assignment,
    lost: Lost<'_>,
    conds: &mut [Option<Conditioner>],
    acts: u64,
) -> Result<Option<Live>, EnvError> {
    let Lost { cause, since } = lost;
    tracing::warn!(actor = ctx.id, server = %on.address, error = %cause, "env session lost; reconnecting");
    let pool = ctx.servers;
    if cause.unreachable() {
        pool.failed(&on.address, cause);
    }
    let mut suspect = matches!(cause, EnvError::Deadline { .. }).then(|| on.address.clone());
    let mut backoff = Backoff::new(pool.deadlines());
    let mut last = None;
    loop {
        if ctx.ended() {
            return Ok(None);
        }
        let mut order = pool.candidates(&on.address).await;
        if let Some(i) = suspect
            .take()
            .and_then(|s| order.iter().position(|a| *a == s))
        {
            let slow = order.remove(i);
            order.push(slow);
        }
        for address in order {
            match make_on(ctx, &address, conds, acts).await {
                Ok((live, client)) => {
                    pool.restarted(ctx.id, &on.address, &address, since.elapsed());
                    *on = Assignment { address, client };
                    return Ok(Some(live));
                }
                Err(e) if e.lost_session() => {
                    if e.unreachable() {
                        pool.failed(&address, &e);
                    }
                    tracing::warn!(actor = ctx.id, server = %address, error = %e, "reconnect failed");
                    last = Some(e);
                }
                Err(e) => return Err(e),
            }
        }
        if !backoff.wait().await {
            break;
        }
    }
    let last = last.map_or_else(String::new, |e| format!(" (last attempt: {e})"));
    Err(EnvError::Process(format!(
        "actor {}: could not make the session again within env.deadlines.reconnect_seconds = {} after: {cause}{last}",
        ctx.id,
        pool.deadlines().reconnect_seconds
    )))
}

/// A new session on `address`: a GetVersion within the floor deadline first (Make's
/// own deadline is the ceiling, far too long to learn that a server is silent), then
/// Make and Reset, with few retries (other addresses wait, and rounds back off). The
/// pool's client comes back for the actor's later calls.
async fn make_on(
    ctx: &Sessions<'_>,
    address: &ServerAddress,
    conds: &mut [Option<Conditioner>],
    acts: u64,
) -> Result<(Live, EnvClient), EnvError> {
    let client = ctx.servers.client(address).await?;
    let quick = client.with_retry(RetryPolicy::quick());
    quick.version().await?;
    let live = start(ctx, &quick, conds, acts).await?;
    Ok((live, client))
}
