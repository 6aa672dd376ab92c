//! Which server each actor's session lives on: one channel per server address, actors
//! spread over the addresses, and another address when an actor's server is lost.
//!
//! Sessions hold state on their server, so each actor is pinned to one address (no
//! per-call balancing). The pool's entries ([`ServerSource`]s: plain addresses, `dns:`
//! names, `file:` lists) are resolved at start and again whenever an actor looks for
//! a new home; a resolve that fails keeps the addresses last seen. The learner and the
//! replay never see the pool: a lost server costs only its actors' in-flight episodes.
//!
//! A server that fails `lost_after` times in a row (missed deadlines, refused
//! connections; [`DeadlineConfig`]) counts as lost: actors looking for a new home try
//! it after every other server, until it answers again. The pool also keeps what the
//! run's faults cost ([`EnvFaults`], `summary.json`'s `env_faults`).

use std::collections::BTreeMap;
use std::future::Future;
use std::sync::Mutex;
use std::time::Duration;

use serde::Serialize;

use super::connection::{ConnectionConfig, Credentials};
use super::deadline::{Backoff, DeadlineConfig};
use super::discovery::{ServerAddress, ServerSource};
use super::grpc::{EnvClient, RetryPolicy};
use crate::env::error::EnvError;

/// One `--server` / `env.servers` entry.
#[derive(Debug, Clone)]
struct Entry {
    /// As given (for messages).
    spec: String,
    /// Its parsed form.
    source: ServerSource,
}

/// A server an actor is pinned to.
#[derive(Debug, Clone)]
pub struct Assignment {
    /// Where it is.
    pub address: ServerAddress,
    /// The channel to it.
    pub client: EnvClient,
}

/// The servers one actor had its session on, in order (`summary.json`'s `actor_servers`).
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct ActorServers {
    /// Actor number.
    pub actor: usize,
    /// Every address it was pinned to, first to last.
    pub servers: Vec<String>,
}

/// What a run's env faults cost (`summary.json`'s `env_faults`).
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct EnvFaults {
    /// Calls that got no answer within their deadline (`env.deadlines`).
    pub deadline_misses: u64,
    /// Sessions made again after one was lost, on the same server or another.
    pub restarts: u64,
    /// Of those, the ones made on another server.
    pub moves: u64,
    /// Seconds actors spent from the start of the call that failed to their new
    /// session, summed over restarts.
    pub seconds_lost: f64,
}

/// What the pool learned so far.
#[derive(Debug, Default)]
struct PoolState {
    /// The addresses of the last successful resolve, in entry order.
    known: Vec<ServerAddress>,
    /// One channel per address (dropped when the address stops answering).
    clients: BTreeMap<ServerAddress, EnvClient>,
    /// Actors pinned to each address.
    load: BTreeMap<ServerAddress, usize>,
    /// Every address each actor was pinned to.
    history: BTreeMap<usize, Vec<ServerAddress>>,
    /// Failures in a row of each address (reset when it answers).
    failures: BTreeMap<ServerAddress, u32>,
    /// What the faults cost so far.
    faults: EnvFaults,
}

impl PoolState {
    /// Whether `address` failed often enough in a row to count as lost.
    fn lost(&self, address: &ServerAddress, lost_after: u32) -> bool {
        self.failures.get(address).is_some_and(|&n| n >= lost_after)
    }
}

/// The env servers of a run and the actors on them.
#[derive(Debug)]
pub struct ServerPool {
    entries: Vec<Entry>,
    credentials: Credentials,
    deadlines: DeadlineConfig,
    /// Never held across an await.
    state: Mutex<PoolState>,
}

impl ServerPool {
    /// [`Self::connect_with`] the default deadlines.
    pub async fn connect(
        specs: &[String],
        connection: &ConnectionConfig,
    ) -> Result<Self, EnvError> {
        Self::connect_with(specs, connection, DeadlineConfig::default()).await
    }

    /// Parse `specs`, resolve them and connect to every address found, every call
    /// waiting as `deadlines` say. A plain address that cannot be reached is an error
    /// (as it always was); an address found by a `dns:` or `file:` entry that cannot
    /// be reached is skipped with a warning while another answers.
    pub async fn connect_with(
        specs: &[String],
        connection: &ConnectionConfig,
        deadlines: DeadlineConfig,
    ) -> Result<Self, EnvError> {
        if specs.is_empty() {
            return Err(EnvError::BadInput {
                field: "servers".into(),
                expected: "at least one address".into(),
                got: "none".into(),
            });
        }
        let entries = specs
            .iter()
            .map(|spec| {
                Ok(Entry {
                    spec: spec.clone(),
                    source: ServerSource::parse(spec)?,
                })
            })
            .collect::<Result<Vec<_>, EnvError>>()?;
        let credentials = connection.load()?;
        let mut found: Vec<(ServerAddress, bool)> = Vec::new();
        for entry in &entries {
            for address in entry.source.resolve(&entry.spec).await? {
                if !found.iter().any(|(a, _)| *a == address) {
                    found.push((address, entry.source.is_dynamic()));
                }
            }
        }
        let attempts = futures::future::join_all(found.iter().map(|(address, _)| {
            EnvClient::connect_to(address, &credentials, RetryPolicy::default(), deadlines)
        }))
        .await;
        let mut state = PoolState::default();
        let mut last_error = None;
        for ((address, dynamic), attempt) in found.into_iter().zip(attempts) {
            match attempt {
                Ok(client) => {
                    state.clients.insert(address.clone(), client);
                }
                Err(e) if dynamic => {
                    tracing::warn!(server = %address, error = %e, "skipping a discovered server that does not answer");
                    last_error = Some(e);
                }
                Err(e) => return Err(e),
            }
            state.known.push(address);
        }
        if state.clients.is_empty() {
            return Err(last_error.expect("no clients means a failed connect"));
        }
        tracing::info!(
            servers = state.clients.len(),
            addresses = %state.known.iter().map(ToString::to_string).collect::<Vec<_>>().join(", "),
            "connected to env servers"
        );
        Ok(Self {
            entries,
            credentials,
            deadlines,
            state: Mutex::new(state),
        })
    }

    fn state(&self) -> std::sync::MutexGuard<'_, PoolState> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// How long the run's calls wait.
    pub fn deadlines(&self) -> &DeadlineConfig {
        &self.deadlines
    }

    /// A connected server, the first one found: for one-off sessions (the spec probe,
    /// videos) right after [`Self::connect`], which keeps at least one. Later, when
    /// servers may have gone, [`Self::live`] finds one that answers.
    pub fn first(&self) -> Assignment {
        let state = self.state();
        let (address, client) = state
            .known
            .iter()
            .find_map(|a| state.clients.get(a).map(|c| (a.clone(), c.clone())))
            .expect("connect keeps at least one client");
        Assignment { address, client }
    }

    /// Pin `actor` to the connected address with the fewest actors (the first found on
    /// a tie, so actors go round-robin over a fresh pool).
    pub fn assign(&self, actor: usize) -> Assignment {
        let mut state = self.state();
        let (address, client) = state
            .known
            .iter()
            .filter_map(|a| state.clients.get(a).map(|c| (a, c)))
            .min_by_key(|(a, _)| state.load.get(*a).copied().unwrap_or(0))
            .map(|(a, c)| (a.clone(), c.clone()))
            .expect("connect keeps at least one client");
        *state.load.entry(address.clone()).or_default() += 1;
        state
            .history
            .entry(actor)
            .or_default()
            .push(address.clone());
        Assignment { address, client }
    }

    /// Addresses to try for an actor whose session on `current` was lost, resolved
    /// afresh: `current` first while its entry still lists it and it does not count as
    /// lost (a restarted server takes its actors back), then the others, fewest actors
    /// first, and the lost ones last.
    pub async fn candidates(&self, current: &ServerAddress) -> Vec<ServerAddress> {
        let mut found: Vec<ServerAddress> = Vec::new();
        let mut complete = true;
        for entry in &self.entries {
            match entry.source.resolve(&entry.spec).await {
                Ok(addresses) => {
                    for a in addresses {
                        if !found.contains(&a) {
                            found.push(a);
                        }
                    }
                }
                Err(e) => {
                    tracing::warn!(error = %e, "resolving again failed; keeping the servers last seen");
                    complete = false;
                }
            }
        }
        let mut state = self.state();
        if complete {
            // Channels to servers no entry lists any more go; a server that comes back
            // gets a fresh one.
            state.clients.retain(|a, _| found.contains(a));
            state.known = found;
        } else {
            for a in found {
                if !state.known.contains(&a) {
                    state.known.push(a);
                }
            }
        }
        let lost_after = self.deadlines.lost_after;
        let load = |a: &ServerAddress| state.load.get(a).copied().unwrap_or(0);
        let rank = |a: &ServerAddress| (state.lost(a, lost_after), a != current, load(a));
        let mut ordered: Vec<((bool, bool, usize), usize, ServerAddress)> = state
            .known
            .iter()
            .enumerate()
            .map(|(i, a)| (rank(a), i, a.clone()))
            .collect();
        ordered.sort();
        ordered.into_iter().map(|(_, _, a)| a).collect()
    }

    /// The channel to `address`, made now when there is none (with a few quick attempts:
    /// the caller has other addresses to try).
    pub async fn client(&self, address: &ServerAddress) -> Result<EnvClient, EnvError> {
        if let Some(client) = self.state().clients.get(address) {
            return Ok(client.clone());
        }
        let client = EnvClient::connect_to(
            address,
            &self.credentials,
            RetryPolicy::quick(),
            self.deadlines,
        )
        .await?
        .with_retry(RetryPolicy::default());
        self.state().clients.insert(address.clone(), client.clone());
        Ok(client)
    }

    /// Drop the channel to an address that stopped answering (the next use connects anew).
    pub fn forget(&self, address: &ServerAddress) {
        self.state().clients.remove(address);
    }

    /// `address` did not answer (`error`: a missed deadline, a refused connection):
    /// its channel goes (a blackholed connection would hold every later call too),
    /// and it counts one more failure in a row.
    pub fn failed(&self, address: &ServerAddress, error: &EnvError) {
        let mut state = self.state();
        state.clients.remove(address);
        if matches!(error, EnvError::Deadline { .. }) {
            state.faults.deadline_misses += 1;
        }
        let n = state.failures.entry(address.clone()).or_default();
        *n += 1;
        if *n == self.deadlines.lost_after {
            tracing::warn!(server = %address, failures = *n, "env server counts as lost; actors try it last");
        }
    }

    /// `actor`'s session, lost on `from`, was made again on `to` (`lost`: from the start
    /// of the call that failed until now); `to` answered, so its failures are forgotten.
    pub fn restarted(
        &self,
        actor: usize,
        from: &ServerAddress,
        to: &ServerAddress,
        lost: Duration,
    ) {
        let mut state = self.state();
        state.failures.remove(to);
        state.faults.restarts += 1;
        state.faults.seconds_lost += lost.as_secs_f64();
        if from == to {
            tracing::info!(actor, server = %to, lost_s = lost.as_secs_f64(), "env session made again");
            return;
        }
        tracing::warn!(actor, from = %from, to = %to, lost_s = lost.as_secs_f64(), "env server lost; actor moved to another server");
        state.faults.moves += 1;
        if let Some(n) = state.load.get_mut(from) {
            *n = n.saturating_sub(1);
        }
        *state.load.entry(to.clone()).or_default() += 1;
        state.history.entry(actor).or_default().push(to.clone());
    }

    /// What the run's faults cost so far.
    pub fn faults(&self) -> EnvFaults {
        self.state().faults.clone()
    }

    /// A server that answers now: the first found if it still does, else any other
    /// (the final evaluation must not depend on the one server that went away).
    pub async fn live(&self) -> Result<Assignment, EnvError> {
        // `known` is never empty: connect found an address, and only a complete
        // resolve (every entry gave at least one) replaces it.
        let first = self.state().known[0].clone();
        let mut last_error = None;
        for address in self.candidates(&first).await {
            let client = match self.client(&address).await {
                Ok(client) => client,
                Err(e) => {
                    last_error = Some(e);
                    continue;
                }
            };
            match client.with_retry(RetryPolicy::quick()).version().await {
                Ok(_) => return Ok(Assignment { address, client }),
                Err(e) => {
                    if e.unreachable() {
                        self.failed(&address, &e);
                    } else {
                        self.forget(&address);
                    }
                    last_error = Some(e);
                }
            }
        }
        Err(last_error.unwrap_or_else(|| EnvError::BadInput {
            field: "servers".into(),
            expected: "at least one address".into(),
            got: "none after resolving again".into(),
        }))
    }

    /// `call` on a server that answers ([`Self::live`]), made again on a lost session
    /// or a silent server, with [`Backoff`] between attempts until
    /// `reconnect_seconds` pass: the run's one-off sessions (its spec probe, its final
    /// evaluation) ride out a fault as the actors' sessions do. `what` names the call
    /// in the log.
    pub async fn on_live<T, F, Fut>(&self, what: &'static str, mut call: F) -> Result<T, EnvError>
    where
        F: FnMut(EnvClient) -> Fut,
        Fut: Future<Output = Result<T, EnvError>>,
    {
        let mut backoff = Backoff::new(&self.deadlines);
        loop {
            let (address, error) = match self.live().await {
                Ok(server) => match call(server.client).await {
                    Ok(done) => return Ok(done),
                    Err(e) => (Some(server.address), e),
                },
                Err(e) => (None, e),
            };
            if !error.lost_session() {
                return Err(error);
            }
            if let Some(address) = address.filter(|_| error.unreachable()) {
                self.failed(&address, &error);
            }
            tracing::warn!(what, error = %error, "env call failed; trying again");
            if !backoff.wait().await {
                return Err(error);
            }
        }
    }

    /// Every actor's servers, by actor number.
    pub fn actor_servers(&self) -> Vec<ActorServers> {
        self.state()
            .history
            .iter()
            .map(|(&actor, servers)| ActorServers {
                actor,
                servers: servers.iter().map(ToString::to_string).collect(),
            })
            .collect()
    }
}
