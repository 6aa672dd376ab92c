//! gRPC client for `env_server` (protocol `mo_env.v1`): the only module that sees proto types.
//!
//! Every proto message is converted to the plain types of [`crate::core::spec`] and
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

mod channel;
mod convert;
mod remote;
mod render;
mod status;

use channel::{Bearer, Stub};
pub use remote::RemoteEnv;
pub use status::RetryPolicy;
use status::{chain, is_unavailable, status_error};

use convert::{autoreset_to_proto, missing, objective_from_proto, spec_from_proto};

use super::MakeOptions;
use super::connection::Credentials;
use super::deadline::{CallTimes, DeadlineConfig};
use super::discovery::ServerAddress;
use crate::core::spec::{EnvInfo, ServerVersion};
use crate::env::error::EnvError;

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
        Ok(RemoteEnv::new(
            self.clone(),
            r.session_id,
            spec,
            r.lease_seconds,
            times,
        ))
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
