//! gRPC client for `env_server` (protocol `mo_env.v1`): the only module that sees proto types.
//!
//! Every proto message is converted to the plain types of [`crate::spec`] and
//! [`crate::env`] here, field by field, so a protocol change breaks the build in
//! one place. Only UNAVAILABLE is retried (with exponential backoff); every other
//! status becomes a typed [`EnvError::Status`] carrying the server's message. Every
//! call has a deadline ([`DeadlineConfig`]; a Step's and a Reset's follow the
//! session's measured pace), and a call that misses it is [`EnvError::Deadline`].
//! Servers on other hosts are reached over TLS with a bearer token ([`Credentials`]).

use std::future::Future;
use std::time::{Duration, Instant};

use mo_env_proto::v1 as pb;
use pb::env_service_client::EnvServiceClient;
use tokio::sync::mpsc;
use tokio_stream::wrappers::ReceiverStream;

mod channel;
mod convert;
mod render;
mod status;

use channel::{Bearer, Stub};
pub use status::RetryPolicy;
use status::{chain, is_unavailable, status_error};

use convert::{
    autoreset_to_proto, missing, named_from_proto, objective_from_proto, observation_from_proto,
    spec_from_proto, step_from_proto, tensor_to_proto,
};

use super::connection::Credentials;
use super::deadline::{CallTimes, DeadlineConfig};
use super::discovery::ServerAddress;
use super::{Env, HostTensor, MakeOptions, ResetResult, StepResult};
use crate::error::{EnvError, StatusKind};
use crate::spec::{EnvInfo, EnvSpec, ServerVersion};

/// Largest message the client sends or accepts.
const MAX_MESSAGE_BYTES: usize = 256 << 20;

/// A connection to one env server.
#[derive(Debug, Clone)]
pub struct EnvClient {
    client: Stub,
    address: String,
    retry: RetryPolicy,
    deadlines: DeadlineConfig,
}

impl EnvClient {
    /// Connect to `host:port` (or an `http://` URL), plain and without a token, with
    /// the default retry policy.
    pub async fn connect(address: &str) -> Result<Self, EnvError> {
        Self::connect_with(address, &Credentials::default(), RetryPolicy::default()).await
    }

    /// Connect to `host:port`, `http://` or `https://` with TLS and a token as
    /// `credentials` say, with the default retry policy.
    pub async fn connect_with_credentials(
        address: &str,
        credentials: &Credentials,
    ) -> Result<Self, EnvError> {
        Self::connect_with(address, credentials, RetryPolicy::default()).await
    }

    /// Connect, retrying refused connections per `retry`; a failed TLS handshake is
    /// not retried (the certificates will not change).
    pub async fn connect_with(
        address: &str,
        credentials: &Credentials,
        retry: RetryPolicy,
    ) -> Result<Self, EnvError> {
        let deadlines = DeadlineConfig::default();
        Self::connect_to(
            &ServerAddress::plain(address),
            credentials,
            retry,
            deadlines,
        )
        .await
    }

    /// Connect to a server found by discovery: `server.dial` is dialled and, over TLS,
    /// the certificate must carry `server.tls_name` when set. Calls then wait as
    /// `deadlines` say; a connection not set up within their floor is given up (not
    /// retried: the caller may have other servers).
    pub async fn connect_to(
        server: &ServerAddress,
        credentials: &Credentials,
        retry: RetryPolicy,
        deadlines: DeadlineConfig,
    ) -> Result<Self, EnvError> {
        let address = server.to_string();
        let connect_error = |reason: String| EnvError::Connect {
            address: address.clone(),
            reason,
        };
        let endpoint = channel::endpoint(&server.dial, server.tls_name.as_deref(), credentials)
            .map_err(connect_error)?;
        let bearer = Bearer::new(credentials.token.as_deref()).map_err(connect_error)?;
        let mut attempt = 0;
        let channel = loop {
            let connected = tokio::time::timeout(deadlines.floor(), endpoint.connect()).await;
            let Ok(connected) = connected else {
                return Err(missed(&address, "connect", deadlines.floor()));
            };
            match connected {
                Ok(channel) => break channel,
                Err(e) if channel::is_permanent(&e) => {
                    return Err(connect_error(format!(
                        "TLS handshake failed: {}",
                        chain(&e)
                    )));
                }
                Err(e) if attempt + 1 < retry.max_attempts => {
                    tracing::debug!(%address, attempt, error = %e, "connect failed; retrying");
                    tokio::time::sleep(retry.backoff(attempt)).await;
                    attempt += 1;
                }
                Err(e) => {
                    return Err(connect_error(format!(
                        "{} (after {} attempts)",
                        chain(&e),
                        attempt + 1
                    )));
                }
            }
        };
        let client = EnvServiceClient::with_interceptor(channel, bearer)
            .max_decoding_message_size(MAX_MESSAGE_BYTES)
            .max_encoding_message_size(MAX_MESSAGE_BYTES);
        Ok(Self {
            client,
            address,
            retry,
            deadlines,
        })
    }

    /// The address this client talks to (a resolved one with its DNS name).
    pub fn address(&self) -> &str {
        &self.address
    }

    /// The same channel, retrying UNAVAILABLE per `retry` instead.
    pub fn with_retry(&self, retry: RetryPolicy) -> Self {
        Self {
            retry,
            ..self.clone()
        }
    }

    /// The same channel, its calls waiting as `deadlines` say.
    pub fn with_deadlines(&self, deadlines: DeadlineConfig) -> Self {
        Self {
            deadlines,
            ..self.clone()
        }
    }

    /// How long this client's calls wait.
    pub fn deadlines(&self) -> &DeadlineConfig {
        &self.deadlines
    }

    /// Run one unary call, each attempt bounded by `deadline`, retrying only
    /// UNAVAILABLE with backoff (a missed deadline is not retried here: the actor's
    /// session restart decides where to go next).
    async fn call<Req, Resp, F, Fut>(
        &self,
        name: &'static str,
        deadline: Duration,
        request: Req,
        mut f: F,
    ) -> Result<Resp, EnvError>
    where
        Req: Clone,
        F: FnMut(Stub, Req) -> Fut,
        Fut: Future<Output = Result<tonic::Response<Resp>, tonic::Status>>,
    {
        let mut attempt = 0;
        loop {
            let answer = tokio::time::timeout(deadline, f(self.client.clone(), request.clone()));
            let Ok(answer) = answer.await else {
                return Err(missed(&self.address, name, deadline));
            };
            match answer {
                Ok(response) => return Ok(response.into_inner()),
                Err(status) if is_unavailable(&status) && attempt + 1 < self.retry.max_attempts => {
                    tracing::warn!(
                        call = name,
                        attempt,
                        message = status.message(),
                        "server unavailable; retrying"
                    );
                    tokio::time::sleep(self.retry.backoff(attempt)).await;
                    attempt += 1;
                }
                Err(status) => return Err(status_error(name, &status)),
            }
        }
    }

    /// Protocol version and capabilities.
    pub async fn version(&self) -> Result<ServerVersion, EnvError> {
        let r = self
            .call(
                "GetVersion",
                self.deadlines.floor(),
                pb::GetVersionRequest {},
                |mut c, r| async move { c.get_version(r).await },
            )
            .await?;
        Ok(ServerVersion {
            protocol_version: r.protocol_version,
            server_version: r.server_version,
            capabilities: r.capabilities,
            max_message_bytes: u64::try_from(r.max_message_bytes).unwrap_or(0),
        })
    }

    /// Every env the server ships, with its objectives.
    pub async fn list_envs(&self) -> Result<Vec<EnvInfo>, EnvError> {
        let r = self
            .call(
                "ListEnvs",
                self.deadlines.floor(),
                pb::ListEnvsRequest {},
                |mut c, r| async move { c.list_envs(r).await },
            )
            .await?;
        Ok(r.envs
            .into_iter()
            .map(|e| EnvInfo {
                env_id: e.env_id,
                description: e.description,
                objectives: e.objectives.into_iter().map(objective_from_proto).collect(),
            })
            .collect())
    }

    /// Create a session of `options.num_envs` instances.
    pub async fn make(&self, options: &MakeOptions) -> Result<RemoteEnv, EnvError> {
        let request = pb::MakeRequest {
            env_id: options.env_id.clone(),
            num_envs: i32::try_from(options.num_envs).map_err(|_| EnvError::BadInput {
                field: "num_envs".into(),
                expected: "at most 2^31-1".into(),
                got: options.num_envs.to_string(),
            })?,
            kwargs_json: if options.kwargs.is_empty() {
                String::new()
            } else {
                serde_json::Value::Object(options.kwargs.clone()).to_string()
            },
            seed: options.seed,
            autoreset_mode: autoreset_to_proto(options.autoreset_mode) as i32,
            discount: options.discount,
            info_keys: options.info_keys.clone(),
            num_workers: i32::try_from(options.num_workers).map_err(|_| EnvError::BadInput {
                field: "num_workers".into(),
                expected: "at most 2^31-1".into(),
                got: options.num_workers.to_string(),
            })?,
        };
        let started = Instant::now();
        let r = self
            .call(
                "Make",
                self.deadlines.ceiling(),
                request,
                |mut c, r| async move { c.make(r).await },
            )
            .await?;
        let times = CallTimes::after_make(started.elapsed());
        let spec = spec_from_proto(r.spec.ok_or_else(|| missing("MakeResponse.spec"))?)?;
        Ok(RemoteEnv {
            client: self.clone(),
            session_id: r.session_id,
            spec,
            lease_seconds: r.lease_seconds,
            stream: StreamState::Unary,
            times,
        })
    }
}

/// A session on a server: B instances stepped together.
#[derive(Debug)]
pub struct RemoteEnv {
    client: EnvClient,
    session_id: String,
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

/// The error of a call to `server` that got no answer within `waited`, logged where it
/// happens with the server, the call and the time waited.
fn missed(server: &str, call: &'static str, waited: Duration) -> EnvError {
    tracing::warn!(
        server,
        call,
        waited_s = waited.as_secs_f64(),
        "env server gave no answer within the deadline"
    );
    EnvError::Deadline {
        call,
        server: server.to_string(),
        waited,
    }
}
