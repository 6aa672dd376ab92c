//! A session on a server ([`RemoteEnv`]): Reset, Step (unary, or on one bidirectional
//! stream per session) and Close, each within its deadline, which for Step and Reset
//! follows the session's measured pace ([`CallTimes`]).

use std::time::{Duration, Instant};

use mo_env_proto::v1 as pb;
use tokio::sync::mpsc;
use tokio_stream::wrappers::ReceiverStream;

use super::convert::{named_from_proto, observation_from_proto, step_from_proto, tensor_to_proto};
use super::status::status_error;
use super::{EnvClient, missed};
use crate::core::spec::EnvSpec;
use crate::env::deadline::CallTimes;
use crate::env::error::{EnvError, StatusKind};
use crate::env::{Env, HostTensor, ResetResult, StepResult};

/// A session on a server: B instances stepped together.
#[derive(Debug)]
pub struct RemoteEnv {
    pub(super) client: EnvClient,
    pub(super) session_id: String,
    spec: EnvSpec,
    lease_seconds: f64,
    stream: StreamState,
    /// What this session's calls took, which its Step and Reset deadlines follow.
    times: CallTimes,
}

/// How steps travel: unary calls, or one bidirectional stream.
#[derive(Debug)]
#[allow(
    clippy::large_enum_variant,
    reason = "one per session, replaced rarely; boxing buys nothing"
)]
enum StreamState {
    /// One unary `Step` call per step.
    Unary,
    /// Streaming chosen; the call opens with the next step.
    Idle,
    /// An open `StepStream` call.
    Open {
        requests: mpsc::Sender<pb::StepRequest>,
        responses: tonic::Streaming<pb::StepResponse>,
    },
}

impl RemoteEnv {
    pub(super) fn new(
        client: EnvClient,
        session_id: String,
        spec: EnvSpec,
        lease_seconds: f64,
        times: CallTimes,
    ) -> Self {
        Self {
            client,
            session_id,
            spec,
            lease_seconds,
            stream: StreamState::Unary,
            times,
        }
    }

    /// Server-side session id.
    pub fn session_id(&self) -> &str {
        &self.session_id
    }

    /// Idle time after which the server closes the session.
    pub fn lease_seconds(&self) -> f64 {
        self.lease_seconds
    }

    /// The deadline the next Step waits for (the session's pace, `env.deadlines`).
    pub fn step_deadline(&self) -> Duration {
        self.times.step_deadline(&self.client.deadlines)
    }

    /// Send subsequent steps over one bidirectional stream instead of unary calls.
    /// The server closes the session if the stream breaks.
    pub fn use_stream(&mut self) {
        if matches!(self.stream, StreamState::Unary) {
            self.stream = StreamState::Idle;
        }
    }

    async fn step_streamed(
        &mut self,
        request: pb::StepRequest,
    ) -> Result<pb::StepResponse, EnvError> {
        let stream_closed = || EnvError::Status {
            call: "StepStream",
            code: StatusKind::Unavailable,
            message: "stream closed by the server".into(),
        };
        if let StreamState::Open { requests, .. } = &self.stream {
            if requests.send(request).await.is_err() {
                self.stream = StreamState::Idle;
                return Err(stream_closed());
            }
        } else {
            // Queue the first request before opening the call: the server sends
            // its response headers only with its first message.
            let (requests, rx) = mpsc::channel(2);
            requests.send(request).await.map_err(|_| stream_closed())?;
            let mut client = self.client.client.clone();
            let responses = client
                .step_stream(ReceiverStream::new(rx))
                .await
                .map_err(|s| status_error("StepStream", &s))?
                .into_inner();
            self.stream = StreamState::Open {
                requests,
                responses,
            };
        }
        let StreamState::Open { responses, .. } = &mut self.stream else {
            unreachable!("opened above")
        };
        let outcome = responses.message().await;
        match outcome {
            Ok(Some(response)) => Ok(response),
            Ok(None) => {
                self.stream = StreamState::Idle;
                Err(stream_closed())
            }
            Err(status) => {
                // The call is over; the next step opens a fresh stream.
                self.stream = StreamState::Idle;
                Err(status_error("StepStream", &status))
            }
        }
    }
}

impl Env for RemoteEnv {
    fn spec(&self) -> &EnvSpec {
        &self.spec
    }

    async fn reset(
        &mut self,
        env_indices: &[usize],
        seeds: &[u64],
    ) -> Result<ResetResult, EnvError> {
        let request = pb::ResetRequest {
            session_id: self.session_id.clone(),
            env_indices: env_indices.iter().map(|&i| i as i32).collect(),
            seeds: seeds.to_vec(),
        };
        let deadline = self.times.reset_deadline(&self.client.deadlines);
        let started = Instant::now();
        let r = self
            .client
            .call("Reset", deadline, request, |mut c, r| async move {
                c.reset(r).await
            })
            .await?;
        self.times.reset(started.elapsed());
        Ok(ResetResult {
            observation: observation_from_proto(r.observation)?,
            info: named_from_proto(r.info)?,
        })
    }

    async fn step(&mut self, action: &HostTensor) -> Result<StepResult, EnvError> {
        let request = pb::StepRequest {
            session_id: self.session_id.clone(),
            action: Some(tensor_to_proto(action)),
        };
        let deadline = self.step_deadline();
        let started = Instant::now();
        let r = if !matches!(self.stream, StreamState::Unary) {
            match tokio::time::timeout(deadline, self.step_streamed(request)).await {
                Ok(response) => response?,
                Err(_) => {
                    // The stream is given up (dropping it cancels the call, and the
                    // server closes its sessions when the cancel reaches it).
                    self.stream = StreamState::Idle;
                    return Err(missed(&self.client.address, "StepStream", deadline));
                }
            }
        } else {
            self.client
                .call("Step", deadline, request, |mut c, r| async move {
                    c.step(r).await
                })
                .await?
        };
        self.times.stepped(started.elapsed());
        step_from_proto(r, self.spec.num_envs, self.spec.num_objectives())
    }

    async fn close(self) -> Result<(), EnvError> {
        // Close before the stream (if any) is dropped here: the server also closes a
        // stream's sessions when the stream ends, and Close must not race that.
        let request = pb::CloseRequest {
            session_id: self.session_id.clone(),
        };
        let deadline = self.client.deadlines.floor();
        let closed = self
            .client
            .call(
                "CloseSession",
                deadline,
                request.clone(),
                |mut c, r| async move { c.close_session(r).await },
            )
            .await;
        match closed {
            // A server from before CloseSession knows the call only by its old name.
            Err(EnvError::Status {
                code: StatusKind::Unimplemented,
                ..
            }) => {
                #[allow(deprecated, reason = "the fallback for servers without CloseSession")]
                self.client
                    .call("Close", deadline, request, |mut c, r| async move {
                        c.close(r).await
                    })
                    .await?;
            }
            closed => {
                closed?;
            }
        }
        Ok(())
    }
}
