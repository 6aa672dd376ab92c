//! gRPC client for `env_server` (protocol `mo_env.v1`): the only module that sees proto types.
//!
//! Every proto message is converted to the plain types of [`crate::spec`] and
//! [`crate::env`] here, field by field, so a protocol change breaks the build in
//! one place. Only UNAVAILABLE is retried (with exponential backoff); every other
//! status becomes a typed [`EnvError::Status`] carrying the server's message.

use std::future::Future;
use std::time::Duration;

use mo_env_proto::v1 as pb;
use pb::env_service_client::EnvServiceClient;
use tokio::sync::mpsc;
use tokio_stream::wrappers::ReceiverStream;
use tonic::transport::{Channel, Endpoint};

use super::{
    EpisodeSummary, Env, HostTensor, MakeOptions, NamedTensor, Observation, ResetResult,
    StepResult,
};
use crate::error::{EnvError, StatusKind};
use crate::spec::{
    AutoresetMode, BoxSpace, DType, DiscreteSpace, EnvInfo, EnvSpec, ObjectiveSpec, ServerVersion,
    Space,
};

/// Largest message the client sends or accepts.
const MAX_MESSAGE_BYTES: usize = 256 << 20;

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
    fn backoff(&self, attempt: u32) -> Duration {
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
        _ => StatusKind::Other,
    }
}

/// UNAVAILABLE, or a connection that broke under a call: tonic reports the latter as
/// UNKNOWN with the transport error as its source (a server's own UNKNOWN has none).
fn is_unavailable(status: &tonic::Status) -> bool {
    status.code() == tonic::Code::Unavailable
        || (status.code() == tonic::Code::Unknown && std::error::Error::source(status).is_some())
}

fn status_error(call: &'static str, status: &tonic::Status) -> EnvError {
    let code = if is_unavailable(status) { StatusKind::Unavailable } else { status_kind(status.code()) };
    EnvError::Status { call, code, message: status.message().to_string() }
}

/// A connection to one env server.
#[derive(Debug, Clone)]
pub struct EnvClient {
    client: EnvServiceClient<Channel>,
    address: String,
    retry: RetryPolicy,
}

impl EnvClient {
    /// Connect to `host:port` (or an `http://` URL) with the default retry policy.
    pub async fn connect(address: &str) -> Result<Self, EnvError> {
        Self::connect_with(address, RetryPolicy::default()).await
    }

    /// Connect, retrying refused connections per `retry`.
    pub async fn connect_with(address: &str, retry: RetryPolicy) -> Result<Self, EnvError> {
        let uri = if address.contains("://") { address.to_string() } else { format!("http://{address}") };
        let connect_error = |reason: String| EnvError::Connect { address: address.to_string(), reason };
        let endpoint = Endpoint::from_shared(uri)
            .map_err(|e| connect_error(format!("invalid address: {e}")))?
            .tcp_nodelay(true)
            .connect_timeout(Duration::from_secs(5));
        let mut attempt = 0;
        let channel = loop {
            match endpoint.connect().await {
                Ok(channel) => break channel,
                Err(e) if attempt + 1 < retry.max_attempts => {
                    tracing::debug!(address, attempt, error = %e, "connect failed; retrying");
                    tokio::time::sleep(retry.backoff(attempt)).await;
                    attempt += 1;
                }
                Err(e) => return Err(connect_error(format!("{e} (after {} attempts)", attempt + 1))),
            }
        };
        let client = EnvServiceClient::new(channel)
            .max_decoding_message_size(MAX_MESSAGE_BYTES)
            .max_encoding_message_size(MAX_MESSAGE_BYTES);
        Ok(Self { client, address: address.to_string(), retry })
    }

    /// The address this client talks to.
    pub fn address(&self) -> &str {
        &self.address
    }

    /// Run one unary call, retrying only UNAVAILABLE with backoff.
    async fn call<Req, Resp, F, Fut>(&self, name: &'static str, request: Req, mut f: F) -> Result<Resp, EnvError>
    where
        Req: Clone,
        F: FnMut(EnvServiceClient<Channel>, Req) -> Fut,
        Fut: Future<Output = Result<tonic::Response<Resp>, tonic::Status>>,
    {
        let mut attempt = 0;
        loop {
            match f(self.client.clone(), request.clone()).await {
                Ok(response) => return Ok(response.into_inner()),
                Err(status) if is_unavailable(&status) && attempt + 1 < self.retry.max_attempts => {
                    tracing::warn!(call = name, attempt, message = status.message(), "server unavailable; retrying");
                    tokio::time::sleep(self.retry.backoff(attempt)).await;
                    attempt += 1;
                }
                Err(status) => return Err(status_error(name, &status)),
            }
        }
    }

    /// Protocol version and capabilities.
    pub async fn version(&self) -> Result<ServerVersion, EnvError> {
        let r = self.call("GetVersion", pb::GetVersionRequest {}, |mut c, r| async move { c.get_version(r).await }).await?;
        Ok(ServerVersion {
            protocol_version: r.protocol_version,
            server_version: r.server_version,
            capabilities: r.capabilities,
            max_message_bytes: u64::try_from(r.max_message_bytes).unwrap_or(0),
        })
    }

    /// Every env the server ships, with its objectives.
    pub async fn list_envs(&self) -> Result<Vec<EnvInfo>, EnvError> {
        let r = self.call("ListEnvs", pb::ListEnvsRequest {}, |mut c, r| async move { c.list_envs(r).await }).await?;
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
        };
        let r = self.call("Make", request, |mut c, r| async move { c.make(r).await }).await?;
        let spec = spec_from_proto(r.spec.ok_or_else(|| missing("MakeResponse.spec"))?)?;
        Ok(RemoteEnv { client: self.clone(), session_id: r.session_id, spec, lease_seconds: r.lease_seconds, stream: StreamState::Unary })
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
}

/// How steps travel: unary calls, or one bidirectional stream.
#[derive(Debug)]
#[allow(clippy::large_enum_variant, reason = "one per session, replaced rarely; boxing buys nothing")]
enum StreamState {
    /// One unary `Step` call per step.
    Unary,
    /// Streaming chosen; the call opens with the next step.
    Idle,
    /// An open `StepStream` call.
    Open { requests: mpsc::Sender<pb::StepRequest>, responses: tonic::Streaming<pb::StepResponse> },
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

    /// Send subsequent steps over one bidirectional stream instead of unary calls.
    /// The server closes the session if the stream breaks.
    pub fn use_stream(&mut self) {
        if matches!(self.stream, StreamState::Unary) {
            self.stream = StreamState::Idle;
        }
    }

    async fn step_streamed(&mut self, request: pb::StepRequest) -> Result<pb::StepResponse, EnvError> {
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
            self.stream = StreamState::Open { requests, responses };
        }
        let StreamState::Open { responses, .. } = &mut self.stream else { unreachable!("opened above") };
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

    async fn reset(&mut self, env_indices: &[usize], seeds: &[u64]) -> Result<ResetResult, EnvError> {
        let request = pb::ResetRequest {
            session_id: self.session_id.clone(),
            env_indices: env_indices.iter().map(|&i| i as i32).collect(),
            seeds: seeds.to_vec(),
        };
        let r = self.client.call("Reset", request, |mut c, r| async move { c.reset(r).await }).await?;
        Ok(ResetResult { observation: observation_from_proto(r.observation)?, info: named_from_proto(r.info)? })
    }

    async fn step(&mut self, action: &HostTensor) -> Result<StepResult, EnvError> {
        let request = pb::StepRequest { session_id: self.session_id.clone(), action: Some(tensor_to_proto(action)) };
        let r = if !matches!(self.stream, StreamState::Unary) {
            self.step_streamed(request).await?
        } else {
            self.client.call("Step", request, |mut c, r| async move { c.step(r).await }).await?
        };
        step_from_proto(r, self.spec.num_envs, self.spec.num_objectives())
    }

    async fn close(self) -> Result<(), EnvError> {
        // Close before the stream (if any) is dropped here: the server also closes a
        // stream's sessions when the stream ends, and Close must not race that.
        let request = pb::CloseRequest { session_id: self.session_id.clone() };
        self.client.call("Close", request, |mut c, r| async move { c.close(r).await }).await?;
        Ok(())
    }
}

fn missing(field: &str) -> EnvError {
    EnvError::Protocol { field: field.into(), expected: "a value".into(), got: "nothing".into() }
}

fn dtype_from_proto(raw: i32, field: &str) -> Result<DType, EnvError> {
    Ok(match pb::DType::try_from(raw) {
        Ok(pb::DType::DtypeFloat32) => DType::Float32,
        Ok(pb::DType::DtypeFloat64) => DType::Float64,
        Ok(pb::DType::DtypeInt32) => DType::Int32,
        Ok(pb::DType::DtypeInt64) => DType::Int64,
        Ok(pb::DType::DtypeUint8) => DType::Uint8,
        Ok(pb::DType::DtypeBool) => DType::Bool,
        Ok(pb::DType::DtypeUnspecified) | Err(_) => {
            return Err(EnvError::Protocol { field: field.into(), expected: "a known dtype".into(), got: raw.to_string() });
        }
    })
}

fn dtype_to_proto(dtype: DType) -> pb::DType {
    match dtype {
        DType::Float32 => pb::DType::DtypeFloat32,
        DType::Float64 => pb::DType::DtypeFloat64,
        DType::Int32 => pb::DType::DtypeInt32,
        DType::Int64 => pb::DType::DtypeInt64,
        DType::Uint8 => pb::DType::DtypeUint8,
        DType::Bool => pb::DType::DtypeBool,
    }
}

fn shape_from_proto(shape: &[i64], field: &str) -> Result<Vec<usize>, EnvError> {
    shape
        .iter()
        .map(|&d| {
            usize::try_from(d).map_err(|_| EnvError::Protocol {
                field: field.into(),
                expected: "non-negative dimensions".into(),
                got: format!("{shape:?}"),
            })
        })
        .collect()
}

fn tensor_from_proto(t: pb::Tensor, field: &str) -> Result<HostTensor, EnvError> {
    let dtype = dtype_from_proto(t.dtype, field)?;
    let shape = shape_from_proto(&t.shape, field)?;
    let expected = shape.iter().product::<usize>() * dtype.itemsize();
    if t.data.len() != expected {
        return Err(EnvError::Protocol {
            field: field.into(),
            expected: format!("{expected} bytes for {} {shape:?}", dtype.name()),
            got: format!("{} bytes", t.data.len()),
        });
    }
    Ok(HostTensor { dtype, shape, data: t.data.to_vec() })
}

fn tensor_to_proto(t: &HostTensor) -> pb::Tensor {
    pb::Tensor {
        dtype: dtype_to_proto(t.dtype) as i32,
        shape: t.shape.iter().map(|&d| d as i64).collect(),
        data: t.data.clone().into(),
    }
}

fn named_from_proto(leaves: Vec<pb::NamedTensor>) -> Result<Vec<NamedTensor>, EnvError> {
    leaves
        .into_iter()
        .map(|l| {
            let field = format!("tensor '{}'", l.name);
            let tensor = tensor_from_proto(l.tensor.ok_or_else(|| missing(&field))?, &field)?;
            Ok(NamedTensor { name: l.name, tensor })
        })
        .collect()
}

fn observation_from_proto(leaves: Vec<pb::NamedTensor>) -> Result<Observation, EnvError> {
    Ok(Observation { leaves: named_from_proto(leaves)? })
}

fn step_from_proto(r: pb::StepResponse, num_envs: usize, k: usize) -> Result<StepResult, EnvError> {
    let reward = tensor_from_proto(r.reward.ok_or_else(|| missing("StepResponse.reward"))?, "reward")?;
    if reward.dtype != DType::Float32 || reward.shape != [num_envs, k] {
        return Err(EnvError::Protocol {
            field: "StepResponse.reward".into(),
            expected: format!("float32 [{num_envs}, {k}]"),
            got: format!("{} {:?}", reward.dtype.name(), reward.shape),
        });
    }
    for (name, flags) in [("terminated", &r.terminated), ("truncated", &r.truncated)] {
        if flags.len() != num_envs {
            return Err(EnvError::Protocol {
                field: format!("StepResponse.{name}"),
                expected: format!("{num_envs} flags"),
                got: flags.len().to_string(),
            });
        }
    }
    let episodes = r
        .episodes
        .into_iter()
        .map(|e| EpisodeSummary {
            env_index: e.env_index as usize,
            episode_return: e.episode_return,
            discounted_return: e.discounted_return,
            length: e.length as u64,
            terminated: e.terminated,
            truncated: e.truncated,
        })
        .collect();
    Ok(StepResult {
        observation: observation_from_proto(r.observation)?,
        reward: reward.to_f32_vec(),
        terminated: r.terminated,
        truncated: r.truncated,
        info: named_from_proto(r.info)?,
        episodes,
        final_observation: observation_from_proto(r.final_observation)?,
    })
}

fn objective_from_proto(o: pb::ObjectiveSpec) -> ObjectiveSpec {
    ObjectiveSpec { name: o.name, description: o.description, min: o.min, max: o.max }
}

fn space_from_proto(space: pb::Space, field: &str) -> Result<Space, EnvError> {
    match space.kind {
        Some(pb::space::Kind::Box(b)) => {
            let shape = shape_from_proto(&b.shape, field)?;
            let numel: usize = shape.iter().product();
            let broadcast = |values: Vec<f64>, which: &str| match values.len() {
                1 => Ok(vec![values[0]; numel]),
                n if n == numel => Ok(values),
                n => Err(EnvError::Protocol {
                    field: format!("{field}.{which}"),
                    expected: format!("1 or {numel} values"),
                    got: n.to_string(),
                }),
            };
            Ok(Space::Box(BoxSpace {
                dtype: dtype_from_proto(b.dtype, field)?,
                low: broadcast(b.low, "low")?,
                high: broadcast(b.high, "high")?,
                shape,
            }))
        }
        Some(pb::space::Kind::Discrete(d)) => Ok(Space::Discrete(DiscreteSpace { n: d.n, start: d.start })),
        Some(pb::space::Kind::Dict(d)) => d
            .entries
            .into_iter()
            .map(|e| {
                let sub = format!("{field}.{}", e.name);
                let space = space_from_proto(e.space.ok_or_else(|| missing(&sub))?, &sub)?;
                Ok((e.name, space))
            })
            .collect::<Result<_, _>>()
            .map(Space::Dict),
        None => Err(missing(field)),
    }
}

fn autoreset_to_proto(mode: AutoresetMode) -> pb::AutoresetMode {
    match mode {
        AutoresetMode::SameStep => pb::AutoresetMode::SameStep,
        AutoresetMode::NextStep => pb::AutoresetMode::NextStep,
        AutoresetMode::Disabled => pb::AutoresetMode::Disabled,
    }
}

fn autoreset_from_proto(raw: i32) -> AutoresetMode {
    match pb::AutoresetMode::try_from(raw) {
        Ok(pb::AutoresetMode::NextStep) => AutoresetMode::NextStep,
        Ok(pb::AutoresetMode::Disabled) => AutoresetMode::Disabled,
        _ => AutoresetMode::SameStep,
    }
}

fn spec_from_proto(s: pb::EnvSpec) -> Result<EnvSpec, EnvError> {
    Ok(EnvSpec {
        env_id: s.env_id,
        num_envs: usize::try_from(s.num_envs).map_err(|_| missing("EnvSpec.num_envs"))?,
        observation_space: space_from_proto(
            s.observation_space.ok_or_else(|| missing("EnvSpec.observation_space"))?,
            "observation_space",
        )?,
        action_space: space_from_proto(s.action_space.ok_or_else(|| missing("EnvSpec.action_space"))?, "action_space")?,
        objectives: s.objectives.into_iter().map(objective_from_proto).collect(),
        max_episode_steps: u64::try_from(s.max_episode_steps).ok().filter(|&n| n > 0),
        autoreset_mode: autoreset_from_proto(s.autoreset_mode),
        discount: s.discount,
        info_keys: s.info_keys,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tensor_round_trip_preserves_bytes() {
        let t = HostTensor::from_f32(vec![2, 3], &[1.0, -2.0, 3.5, 0.0, f32::MAX, -0.25]);
        let back = tensor_from_proto(tensor_to_proto(&t), "t").unwrap();
        assert_eq!(back, t);
        assert_eq!(back.to_f32_vec(), vec![1.0, -2.0, 3.5, 0.0, f32::MAX, -0.25]);
    }

    #[test]
    fn tensor_with_wrong_byte_count_is_a_protocol_error() {
        let mut p = tensor_to_proto(&HostTensor::from_i64(vec![2], &[1, 2]));
        p.data = p.data.slice(0..12);
        let err = tensor_from_proto(p, "action").unwrap_err().to_string();
        assert!(err.contains("expected 16 bytes for int64 [2]"), "{err}");
        assert!(err.contains("got 12 bytes"), "{err}");
    }

    #[test]
    fn box_bounds_broadcast_from_one_value() {
        let space = pb::Space {
            kind: Some(pb::space::Kind::Box(pb::BoxSpace {
                dtype: pb::DType::DtypeFloat32 as i32,
                shape: vec![3],
                low: vec![-1.0],
                high: vec![1.0, 2.0, 3.0],
            })),
        };
        let Space::Box(b) = space_from_proto(space, "action_space").unwrap() else { panic!("not a box") };
        assert_eq!(b.low, vec![-1.0; 3]);
        assert_eq!(b.high, vec![1.0, 2.0, 3.0]);
    }

    #[test]
    fn backoff_grows_and_caps() {
        let p = RetryPolicy::default();
        assert_eq!(p.backoff(0), Duration::from_millis(100));
        assert!((p.backoff(1).as_secs_f64() - 0.15).abs() < 1e-9);
        assert_eq!(p.backoff(30), Duration::from_secs(5));
    }
}
