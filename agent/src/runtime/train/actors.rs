//! A population run's actors (Algorithm 2; docs/design.md, "Populations"): which members
//! share an env session, and the actor tasks that step them.
//!
//! Off-policy members share one session per actor, stepped by one call. On-policy
//! members each get their own actors and sessions (see `spawn_actors`).

use std::panic::AssertUnwindSafe;
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};

use futures::FutureExt;
use tch::Device;
use tokio::task::JoinHandle;

use super::{Population, TrainError, panic_message};
use crate::core::nets::ActorPolicy;
use crate::core::random::{Purpose, StreamKey};
use crate::env::MakeOptions;
use crate::runtime::actor::{ActorContext, ActorMember, run_actor};
use crate::runtime::env_setup::make_options;
use crate::runtime::schedule::Schedule;

/// Starts every actor of `population`; an actor's error or panic calls `stop_all` with
/// its message.
pub(super) fn spawn_actors(
    population: &Population,
    stop_all: &(impl Fn(Option<String>) + Clone + Send + 'static),
) -> Result<Vec<JoinHandle<()>>, TrainError> {
    let runs = &population.runs;
    let num_actors = population.cfg.env.num_actors;
    // Off-policy members share one session per actor, stepped by one call: their
    // learner allowances grow with the same env steps, so acting in lockstep is what
    // each would do alone. An on-policy member's allowance follows its own episode
    // ends (each ends an unroll), so each gets its own actor and session and acts, as
    // alone, only with the policy of every step it has allowed.
    let parties: Vec<Vec<usize>> = if population.layout.on_policy {
        (0..runs.len()).map(|p| vec![p]).collect()
    } else {
        vec![(0..runs.len()).collect()]
    };
    let actors_left: Vec<Arc<AtomicUsize>> = runs
        .iter()
        .map(|_| Arc::new(AtomicUsize::new(num_actors)))
        .collect();
    let mut actors = Vec::new();
    for (a, party) in (0..num_actors).flat_map(|a| parties.iter().map(move |p| (a, p))) {
        let ctx = actor_context(population, a, party)?;
        let ended: Vec<PartyMember> = party
            .iter()
            .map(|&p| PartyMember {
                actors_left: actors_left[p].clone(),
                schedule: runs[p].schedule.clone(),
            })
            .collect();
        actors.push(tokio::spawn(run_and_report(ctx, ended, stop_all.clone())));
    }
    Ok(actors)
}

/// Actor `a`'s context for the members of `party`: their policies and random streams,
/// and the session it makes (the party's first member's env seeds).
fn actor_context(
    population: &Population,
    a: usize,
    party: &[usize],
) -> Result<ActorContext, TrainError> {
    let Population {
        cfg,
        runs,
        dims,
        servers,
        grid,
        layout,
        ..
    } = population;
    let mut members = Vec::with_capacity(party.len());
    for run in party.iter().map(|&p| &runs[p]) {
        let mut policy = ActorPolicy::new(&run.cfg.learner.network, dims, Device::Cpu);
        policy
            .load(&run.params.borrow())
            .map_err(|e| TrainError::Stopped(e.to_string()))?;
        let seed = run.cfg.seed;
        members.push(ActorMember {
            policy,
            sampling: StreamKey::new(seed, Purpose::Acting, a as u64),
            first_seed: seed + 1000 * a as u64,
            env_seeds: StreamKey::new(seed, Purpose::EnvSeeds, a as u64),
            params: run.params.clone(),
            schedule: run.schedule.clone(),
            files: run.files.clone(),
            preferences: grid
                .clone()
                .map(|g| (g, StreamKey::new(seed, Purpose::ActingPreference, a as u64))),
        });
    }
    let first = &runs[party[0]];
    Ok(ActorContext {
        id: a,
        server: servers.assign(a),
        servers: servers.clone(),
        make: MakeOptions {
            num_workers: cfg.env.workers,
            ..make_options(
                &first.cfg,
                cfg.env.num_envs,
                first.cfg.seed + 1000 * a as u64,
            )
        },
        members,
        first_act: first.first_acts.get(a).copied().unwrap_or(0),
        layout: *layout,
        total_env_steps: cfg.run.total_env_steps,
    })
}

/// A member an actor steps: how many of its actors are still running, and its schedule.
struct PartyMember {
    actors_left: Arc<AtomicUsize>,
    schedule: Arc<Schedule>,
}

/// Runs one actor to its end. A panic stops the run as an error does, at once and with
/// its message: the other actors and the learner stop, and the run exits non-zero.
async fn run_and_report(
    ctx: ActorContext,
    party: Vec<PartyMember>,
    stop_all: impl Fn(Option<String>),
) {
    let a = ctx.id;
    match AssertUnwindSafe(run_actor(ctx)).catch_unwind().await {
        Ok(Ok(())) => {
            // A member whose actors have all spent its budget ends now, so that the
            // learner's lockstep no longer waits for its steps.
            for member in party {
                if member.actors_left.fetch_sub(1, Ordering::SeqCst) == 1 {
                    member.schedule.stop(None);
                }
            }
        }
        Ok(Err(e)) => stop_all(Some(format!("actor {a}: {e}"))),
        Err(panic) => stop_all(Some(format!(
            "actor {a} panicked: {}",
            panic_message(panic.as_ref())
        ))),
    }
}
