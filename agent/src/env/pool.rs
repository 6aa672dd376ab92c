//! Which server each actor's session lives on: one channel per server address, actors
//! spread over the addresses, and another address when an actor's server is lost.
//!
//! Sessions hold state on their server, so each actor is pinned to one address (no
//! per-call balancing). The pool's entries ([`ServerSource`]s: plain addresses, `dns:`
//! names, `file:` lists) are resolved at start and again whenever an actor looks for
//! a new home; a resolve that fails keeps the addresses last seen. The learner and the
//! replay never see the pool: a lost server costs only its actors' in-flight episodes.

use std::collections::BTreeMap;
use std::sync::Mutex;

use serde::Serialize;

use super::connection::{ConnectionConfig, Credentials};
use super::discovery::{ServerAddress, ServerSource};
use super::grpc::{EnvClient, RetryPolicy};
use crate::error::EnvError;

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
}

/// The env servers of a run and the actors on them.
#[derive(Debug)]
pub struct ServerPool {
    entries: Vec<Entry>,
    credentials: Credentials,
    /// Never held across an await.
    state: Mutex<PoolState>,
}

impl ServerPool {
    /// Parse `specs`, resolve them and connect to every address found. A plain address
    /// that cannot be reached is an error (as it always was); an address found by a
    /// `dns:` or `file:` entry that cannot be reached is skipped with a warning while
    /// another answers.
    pub async fn connect(
        specs: &[String],
        connection: &ConnectionConfig,
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
            EnvClient::connect_to(address, &credentials, RetryPolicy::default())
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
            state: Mutex::new(state),
        })
    }

    fn state(&self) -> std::sync::MutexGuard<'_, PoolState> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// A connected server, the first one found: for one-off sessions (the spec probe,
    /// videos) at the start of a run.
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
    /// afresh: `current` first while its entry still lists it (a restarted server takes
    /// its actors back), then the others, fewest actors first.
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
        let load = |a: &ServerAddress| state.load.get(a).copied().unwrap_or(0);
        let mut others: Vec<(usize, usize, ServerAddress)> = state
            .known
            .iter()
            .enumerate()
            .filter(|(_, a)| *a != current)
            .map(|(i, a)| (load(a), i, a.clone()))
            .collect();
        others.sort();
        let mut ordered = Vec::with_capacity(others.len() + 1);
        if state.known.contains(current) {
            ordered.push(current.clone());
        }
        ordered.extend(others.into_iter().map(|(_, _, a)| a));
        ordered
    }

    /// The channel to `address`, made now when there is none (with a few quick attempts:
    /// the caller has other addresses to try).
    pub async fn client(&self, address: &ServerAddress) -> Result<EnvClient, EnvError> {
        if let Some(client) = self.state().clients.get(address) {
            return Ok(client.clone());
        }
        let client = EnvClient::connect_to(address, &self.credentials, RetryPolicy::quick())
            .await?
            .with_retry(RetryPolicy::default());
        self.state().clients.insert(address.clone(), client.clone());
        Ok(client)
    }

    /// Drop the channel to an address that stopped answering (the next use connects anew).
    pub fn forget(&self, address: &ServerAddress) {
        self.state().clients.remove(address);
    }

    /// `actor` now has its session on `to` instead of `from`.
    pub fn moved(&self, actor: usize, from: &ServerAddress, to: &ServerAddress) {
        tracing::warn!(actor, from = %from, to = %to, "env server lost; actor moved to another server");
        let mut state = self.state();
        if let Some(n) = state.load.get_mut(from) {
            *n = n.saturating_sub(1);
        }
        *state.load.entry(to.clone()).or_default() += 1;
        state.history.entry(actor).or_default().push(to.clone());
    }

    /// A server that answers now: the first found if it still does, else any other
    /// (the final evaluation must not depend on the one server that went away).
    pub async fn live(&self) -> Result<Assignment, EnvError> {
        let first = self.first();
        let mut last_error = None;
        for address in self.candidates(&first.address).await {
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
                    self.forget(&address);
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
