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

use super::{MemberRun, TrainError, panic_message};
use crate::core::algo::objectives::LearnerDims;
use crate::core::algo::preferences::PreferenceGrid;
use crate::core::nets::ActorPolicy;
use crate::core::random::{Purpose, StreamKey};
use crate::core::replay::SnippetLayout;
use crate::env::MakeOptions;
use crate::env::pool::ServerPool;
use crate::runtime::actor::{ActorContext, ActorMember, run_actor};
use crate::runtime::env_setup::make_options;
use crate::runtime::run_config::TrainConfig;
use crate::runtime::schedule::Schedule;

/// What the actors of a population run are made from.
pub(super) struct ActorPlan<'a> {
    /// The first member's config (env, actors, budget: shared by all members).
    pub cfg: &'a TrainConfig,
    /// The members' runs, in member order.
    pub runs: &'a [MemberRun],
    /// The learner's dimensions (the actors' policies have the same).
    pub dims: &'a LearnerDims,
    /// The run's servers.
    pub servers: &'a Arc<ServerPool>,
    /// An ε-conditioned run's preference grid.
    pub grid: Option<&'a Arc<PreferenceGrid>>,
    /// Snippet sizes of the replays.
    pub layout: SnippetLayout,
}

/// Starts every actor of `plan`; an actor's error or panic calls `stop_all` with its
/// message.
pub(super) fn spawn_actors(
    plan: &ActorPlan<'_>,
    stop_all: &(impl Fn(Option<String>) + Clone + Send + 'static),
) -> Result<Vec<JoinHandle<()>>, TrainError> {
    let ActorPlan {
        cfg,
        runs,
        dims,
        servers,
        grid,
        layout,
    } = *plan;
    // Off-policy members share one session per actor, stepped by one call: their
    // learner allowances grow with the same env steps, so acting in lockstep is what
    // each would do alone. An on-policy member's allowance follows its own episode
    // ends (each ends an unroll), so each gets its own actor and session and acts, as
    // alone, only with the policy of every step it has allowed.
    let parties: Vec<Vec<usize>> = if layout.on_policy {
        (0..runs.len()).map(|p| vec![p]).collect()
    } else {
        vec![(0..runs.len()).collect()]
    };
    let actors_left: Vec<Arc<AtomicUsize>> = runs
        .iter()
        .map(|_| Arc::new(AtomicUsize::new(cfg.env.num_actors)))
        .collect();
    let mut actors = Vec::new();
    for (a, party) in (0..cfg.env.num_actors).flat_map(|a| parties.iter().map(move |p| (a, p))) {
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
                    .cloned()
                    .map(|g| (g, StreamKey::new(seed, Purpose::ActingPreference, a as u64))),
            });
        }
        let first = &runs[party[0]];
        let ctx = ActorContext {
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
            layout,
            total_env_steps: cfg.run.total_env_steps,
        };
        let stop_all = stop_all.clone();
        let ended: Vec<(Arc<AtomicUsize>, Arc<Schedule>)> = party
            .iter()
            .map(|&p| (actors_left[p].clone(), runs[p].schedule.clone()))
            .collect();
        actors.push(tokio::spawn(async move {
            // A panic stops the run as an error does, at once and with its message:
            // the other actors and the learner stop, and the run exits non-zero.
            match AssertUnwindSafe(run_actor(ctx)).catch_unwind().await {
                Ok(Ok(())) => {
                    // A member whose actors have all spent its budget ends now, so
                    // that the learner's lockstep no longer waits for its steps.
                    for (left, schedule) in ended {
                        if left.fetch_sub(1, Ordering::SeqCst) == 1 {
                            schedule.stop(None);
                        }
                    }
                }
                Ok(Err(e)) => stop_all(Some(format!("actor {a}: {e}"))),
                Err(panic) => stop_all(Some(format!(
                    "actor {a} panicked: {}",
                    panic_message(panic.as_ref())
                ))),
            }
        }));
    }

    Ok(actors)
}
