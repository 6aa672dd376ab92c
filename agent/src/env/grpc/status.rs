//! What a gRPC status means to the agent: the typed error it becomes, which statuses are
//! retried (UNAVAILABLE and broken connections), and the backoff between attempts.

use std::time::Duration;

use super::channel;
use crate::env::error::{EnvError, StatusKind};

/// Backoff schedule for UNAVAILABLE (server starting, restarting, or briefly unreachable).
#[derive(Debug, Clone, PartialEq)]
pub struct RetryPolicy {
    /// Attempts in total, including the first.
    pub max_attempts: u32,
    /// Wait before the second attempt.
    pub initial_backoff: Duration,
    /// Growth of the wait per attempt.
    pub multiplier: f64,
    /// Longest single wait.
    pub max_backoff: Duration,
}

impl Default for RetryPolicy {
    /// 10 attempts from 100 ms growing 1.5x up to 5 s: about 25 s in total,
    /// enough to ride out a server restart.
    fn default() -> Self {
        Self {
            max_attempts: 10,
            initial_backoff: Duration::from_millis(100),
            multiplier: 1.5,
            max_backoff: Duration::from_secs(5),
        }
    }
}

impl RetryPolicy {
    /// 3 attempts within about 0.25 s: for probing a server while others could take
    /// its place (the caller backs off between its own rounds).
    pub fn quick() -> Self {
        Self {
            max_attempts: 3,
            ..Self::default()
        }
    }

    pub(super) fn backoff(&self, attempt: u32) -> Duration {
        let secs = self.initial_backoff.as_secs_f64() * self.multiplier.powi(attempt as i32);
        Duration::from_secs_f64(secs.min(self.max_backoff.as_secs_f64()))
    }
}

fn status_kind(code: tonic::Code) -> StatusKind {
    match code {
        tonic::Code::InvalidArgument => StatusKind::InvalidArgument,
        tonic::Code::NotFound => StatusKind::NotFound,
        tonic::Code::FailedPrecondition => StatusKind::FailedPrecondition,
        tonic::Code::ResourceExhausted => StatusKind::ResourceExhausted,
        tonic::Code::Internal => StatusKind::Internal,
        tonic::Code::Unavailable => StatusKind::Unavailable,
        tonic::Code::Unauthenticated => StatusKind::Unauthenticated,
        tonic::Code::Unimplemented => StatusKind::Unimplemented,
        _ => StatusKind::Other,
    }
}

/// UNAVAILABLE, or a connection that broke under a call. tonic reports the latter as
/// CANCELLED ("operation was canceled", when h2 resets the stream) or as UNKNOWN with
/// the transport error as its source (a server's own UNKNOWN has none). This client
/// never cancels its own calls (a dropped call observes no status), so CANCELLED
/// always means the connection went away.
pub(super) fn is_unavailable(status: &tonic::Status) -> bool {
    if channel::rejected_by_tls(status) {
        return false; // the certificates will not change on a retry
    }
    match status.code() {
        tonic::Code::Unavailable | tonic::Code::Cancelled => true,
        tonic::Code::Unknown => std::error::Error::source(status).is_some(),
        _ => false,
    }
}

pub(super) fn status_error(call: &'static str, status: &tonic::Status) -> EnvError {
    let code = if is_unavailable(status) {
        StatusKind::Unavailable
    } else {
        status_kind(status.code())
    };
    // A transport failure's status says only "transport error"; its sources say why.
    let message = match std::error::Error::source(status) {
        Some(source) => format!("{}: {}", status.message(), chain(source)),
        None => status.message().to_string(),
    };
    EnvError::Status {
        call,
        code,
        message,
    }
}

/// An error and its sources, "a: b: c" (tonic's transport errors say little alone).
pub(super) fn chain(error: &dyn std::error::Error) -> String {
    let mut text = error.to_string();
    let mut source = error.source();
    while let Some(e) = source {
        text.push_str(": ");
        text.push_str(&e.to_string());
        source = e.source();
    }
    text
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn backoff_grows_and_caps() {
        let p = RetryPolicy::default();
        assert_eq!(p.backoff(0), Duration::from_millis(100));
        assert!((p.backoff(1).as_secs_f64() - 0.15).abs() < 1e-9);
        assert_eq!(p.backoff(30), Duration::from_secs(5));
    }
}
