//! Errors of the environment side of the agent (client, spawned server, server
//! addresses). This module sits below the rest of `env`: `env`, its submodules and
//! their users import these types, and it imports nothing of theirs.

use crate::core::spec::DType;

/// gRPC status codes the client distinguishes (the rest map to `Other`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StatusKind {
    /// INVALID_ARGUMENT: the request was malformed (action shape, dtype, value...).
    InvalidArgument,
    /// NOT_FOUND: unknown env id or session.
    NotFound,
    /// FAILED_PRECONDITION: e.g. step before reset.
    FailedPrecondition,
    /// RESOURCE_EXHAUSTED: session limit or oversized message.
    ResourceExhausted,
    /// INTERNAL: the simulator raised inside one session.
    Internal,
    /// UNAVAILABLE: the server cannot be reached (retried with backoff).
    Unavailable,
    /// UNAUTHENTICATED: the server takes bearer tokens and this client's is missing or
    /// unknown to it (`--token-file`, `env.connection.token_file`).
    Unauthenticated,
    /// UNIMPLEMENTED: the server does not know the call (an older protocol revision).
    Unimplemented,
    /// Any other code.
    Other,
}

/// Everything that can go wrong talking to an environment.
#[derive(Debug, thiserror::Error)]
pub enum EnvError {
    /// The server could not be reached at all (after retries).
    #[error("cannot connect to env server at {address}: {reason}")]
    Connect {
        /// host:port or URL that was tried.
        address: String,
        /// Transport error text.
        reason: String,
    },
    /// The server answered a call with an error status.
    #[error("{call} failed ({code:?}): {message}")]
    Status {
        /// RPC name, e.g. `Step`.
        call: &'static str,
        /// Status class.
        code: StatusKind,
        /// The server's message (says what was expected and what arrived).
        message: String,
    },
    /// The server sent something that violates the protocol.
    #[error("protocol violation in {field}: expected {expected}, got {got}")]
    Protocol {
        /// Message field that was wrong.
        field: String,
        /// What the protocol requires.
        expected: String,
        /// What arrived.
        got: String,
    },
    /// The caller passed data that does not fit the session's spec.
    #[error("{field}: expected {expected}, got {got}")]
    BadInput {
        /// Argument that was wrong.
        field: String,
        /// What the spec requires.
        expected: String,
        /// What was passed.
        got: String,
    },
    /// A tensor had a dtype the caller did not ask for.
    #[error("{field}: expected dtype {expected:?}, got {got:?}")]
    DType {
        /// Tensor name.
        field: String,
        /// Expected element type.
        expected: DType,
        /// Actual element type.
        got: DType,
    },
    /// A TLS or token file of the connection settings could not be used.
    #[error("env.connection.{field} {path}: {reason}")]
    Credentials {
        /// The `ConnectionConfig` field that names the file.
        field: &'static str,
        /// The file.
        path: std::path::PathBuf,
        /// What was expected and what was found (never the file's content).
        reason: String,
    },
    /// The server did not answer a call within its deadline (`env.deadlines`): it is
    /// slow beyond the session's pace, or unreachable without a refused connection
    /// saying so (a partition, a blackholed route).
    #[error("{call} to {server}: no answer within its deadline of {:.1} s (env.deadlines)", waited.as_secs_f64())]
    Deadline {
        /// RPC name, e.g. `Step`.
        call: &'static str,
        /// The server's address.
        server: String,
        /// How long the call waited.
        waited: std::time::Duration,
    },
    /// A server address (`--server`, `env.servers`) was malformed or resolved to nothing.
    #[error(transparent)]
    Discovery(#[from] DiscoveryError),
    /// Starting or talking to a local env_server process failed.
    #[error("env_server process: {0}")]
    Process(String),
}

/// A server address that could not be used (`--server`, `env.servers`; parsed and
/// resolved by `env::discovery`).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DiscoveryError {
    /// The text is none of the accepted forms.
    #[error("server address {spec:?}: expected {expected}, got {got}")]
    Syntax {
        /// The address as given.
        spec: String,
        /// The form that was expected.
        expected: String,
        /// What was found instead.
        got: String,
    },
    /// A `dns:` name gave no address.
    #[error(
        "server address {spec:?}: expected {name} to resolve to at least one address, got {reason}"
    )]
    Lookup {
        /// The address as given.
        spec: String,
        /// The DNS name looked up.
        name: String,
        /// The resolver's answer (no records, timeout, ...).
        reason: String,
    },
    /// A `file:` list could not be read or holds no usable address.
    #[error("server address {spec:?}: expected {expected}, got {got}")]
    File {
        /// The address as given.
        spec: String,
        /// What the file must hold.
        expected: String,
        /// What was read.
        got: String,
    },
}

impl EnvError {
    /// The status class of a server error, if this is one.
    pub fn status_kind(&self) -> Option<StatusKind> {
        match self {
            EnvError::Status { code, .. } => Some(*code),
            _ => None,
        }
    }

    /// The server did not answer at all (refused, broken or silent connection), as
    /// opposed to answering with an error.
    pub fn unreachable(&self) -> bool {
        self.status_kind() == Some(StatusKind::Unavailable)
            || matches!(self, EnvError::Connect { .. } | EnvError::Deadline { .. })
    }

    /// The session is lost (its server unreachable, silent or restarted, which answers
    /// NOT_FOUND), as opposed to an error a new session would meet again.
    pub fn lost_session(&self) -> bool {
        self.unreachable() || self.status_kind() == Some(StatusKind::NotFound)
    }
}
