//! `mo_env.v1.EnvService` answered by the Python service object.
//!
//! Step and StepStream call Python inline on the front thread (the hot path: no hop).
//! The other RPCs are submitted to the Python asyncio loop as serialized requests and
//! answered through a `Reply`; a client that goes away cancels its pending call, as
//! grpc.aio does (a Make whose client left closes the session it built).
//!
//! With tokens, every call is authenticated first (`auth.rs`) and the caller's client
//! name goes to Python with the call, which binds sessions to it.

use std::pin::Pin;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use bytes::Bytes;
use futures::{FutureExt, Stream, StreamExt};
use mo_env_proto::v1::{
    CloseRequest, CloseResponse, GetVersionRequest, GetVersionResponse, ListEnvsRequest,
    ListEnvsResponse, MakeRequest, MakeResponse, RenderRequest, RenderResponse, ResetRequest,
    ResetResponse, StepRequest, StepResponse,
};
use prost::Message;
use pyo3::prelude::*;
use pyo3::types::PyBytes;
use tokio::sync::oneshot;
use tonic::{Code, Request, Response, Status, Streaming};

use crate::auth::{self, Tokens};
use crate::pb::env_service_server::EnvService;
use crate::{codec, status};

/// What a submitted unary call answers: a serialized response or a status.
type Outcome = Result<Bytes, Status>;

/// The answer channel of one submitted unary call; Python calls exactly one method.
#[pyclass(frozen, module = "env_server_native")]
pub struct Reply {
    tx: Mutex<Option<oneshot::Sender<Outcome>>>,
}

#[pymethods]
impl Reply {
    /// Answer with a serialized response message.
    fn ok(&self, response: &Bound<'_, PyBytes>) {
        self.send(Ok(Bytes::copy_from_slice(response.as_bytes())));
    }

    /// Answer with a status (`code_name` as in `grpc.StatusCode`).
    fn error(&self, code_name: &str, message: &str) {
        self.send(Err(status::from_code_name(code_name, message)));
    }
}

impl Reply {
    fn send(&self, outcome: Outcome) {
        if let Some(tx) = self.tx.lock().expect("reply poisoned").take() {
            let _ = tx.send(outcome); // the client may have gone; nothing to tell it
        }
    }
}

/// Cancels a submitted Python call unless disarmed (the client went away first).
struct CancelOnDrop(Option<Py<PyAny>>);

impl Drop for CancelOnDrop {
    fn drop(&mut self) {
        if let Some(future) = self.0.take() {
            Python::attach(|py| {
                let _ = future.bind(py).call_method0("cancel");
            });
        }
    }
}

/// The tonic service over a Python `env_server.service.EnvService`.
pub(crate) struct PyEnvService {
    service: Arc<Py<PyAny>>,
    busy_poll: Option<Duration>,
    tokens: Option<Tokens>,
}

impl PyEnvService {
    pub(crate) fn new(
        service: Py<PyAny>,
        busy_poll: Option<Duration>,
        tokens: Option<Tokens>,
    ) -> Self {
        Self {
            service: Arc::new(service),
            busy_poll,
            tokens,
        }
    }

    /// The caller's client name (None without tokens), or UNAUTHENTICATED.
    fn owner<T>(&self, request: &Request<T>) -> Result<Option<String>, Status> {
        auth::owner(self.tokens.as_ref(), request.metadata())
    }

    /// Run `method` on the Python asyncio loop and wait for its reply.
    async fn unary<Req: Message, Resp: Message + Default>(
        &self,
        method: &'static str,
        request: Request<Req>,
    ) -> Result<Response<Resp>, Status> {
        let owner = self.owner(&request)?;
        let data = request.into_inner().encode_to_vec();
        let (tx, rx) = oneshot::channel();
        let future = Python::attach(|py| {
            let reply = Py::new(
                py,
                Reply {
                    tx: Mutex::new(Some(tx)),
                },
            )?;
            let args = (method, PyBytes::new(py, &data), reply, owner);
            self.service
                .bind(py)
                .call_method1("submit", args)
                .map(Bound::unbind)
        })
        .map_err(|err| Python::attach(|py| status::from_pyerr(py, &self.service, err)))?;
        let mut pending = CancelOnDrop(Some(future));
        let outcome = rx.await;
        pending.0 = None;
        let response = outcome.map_err(|_| {
            Status::internal(format!("env_server bug: {method} ended without a reply"))
        })??;
        Resp::decode(response).map(Response::new).map_err(|e| {
            Status::internal(format!(
                "env_server bug: {method} replied with an undecodable message: {e}"
            ))
        })
    }
}

/// One Step of client `owner` through `target` (the service, or a stream's step
/// state), inline.
fn step_with(
    service: &Py<PyAny>,
    target: &Py<PyAny>,
    request: StepRequest,
    owner: Option<&str>,
) -> Result<StepResponse, Status> {
    let action = request.action.unwrap_or_default();
    let encoded = Python::attach(|py| {
        let args = (
            request.session_id,
            action.dtype,
            action.shape,
            PyBytes::new(py, &action.data),
            owner,
        );
        match target.bind(py).call_method1("step", args) {
            Ok(response) => match response.cast::<PyBytes>() {
                Ok(bytes) => Ok(Bytes::copy_from_slice(bytes.as_bytes())),
                Err(_) => Err(Status::internal(
                    "env_server bug: step returned something other than bytes",
                )),
            },
            Err(err) => Err(status::from_pyerr(py, service, err)),
        }
    })?;
    StepResponse::decode(encoded).map_err(|e| {
        Status::internal(format!(
            "env_server bug: step returned an undecodable StepResponse: {e}"
        ))
    })
}

/// A StepStream's Python state; `finish(aborted)` runs exactly once, also when the
/// client vanishes and tonic drops the stream.
struct StreamSteps {
    service: Arc<Py<PyAny>>,
    steps: Option<Py<PyAny>>,
}

impl StreamSteps {
    fn finish(&mut self, aborted: bool) {
        if let Some(steps) = self.steps.take() {
            Python::attach(|py| {
                if let Err(err) = steps.bind(py).call_method1("finish", (aborted,)) {
                    err.print(py);
                }
            });
        }
    }
}

impl Drop for StreamSteps {
    fn drop(&mut self) {
        self.finish(false);
    }
}

/// The state `StepStream`'s response stream unfolds over.
struct StreamState {
    inbound: Streaming<StepRequest>,
    steps: StreamSteps,
    busy_poll: Option<Duration>,
    owner: Option<String>,
}

impl StreamState {
    /// The next request, polled without sleeping for up to `window` first: a thread
    /// that parks between Steps wakes to cold caches on a vCPU the host may have
    /// descheduled (on the 2-vCPU bench machine the next simulator step ran 0.1 ms
    /// slower after 100 us of sleep than back to back). Yielding lets the runtime
    /// poll the socket each turn.
    async fn next_request_busy(&mut self, window: Duration) -> Option<Result<StepRequest, Status>> {
        let deadline = Instant::now() + window;
        loop {
            if let Some(next) = self.inbound.next().now_or_never() {
                return next;
            }
            if Instant::now() >= deadline {
                return self.inbound.next().await;
            }
            tokio::task::yield_now().await;
        }
    }

    /// The next response, or None once the stream has ended (and finished).
    async fn next(&mut self) -> Option<Result<StepResponse, Status>> {
        self.steps.steps.as_ref()?;
        let next = match self.busy_poll {
            Some(window) => self.next_request_busy(window).await,
            None => self.inbound.next().await,
        };
        match next {
            Some(Ok(request)) => {
                let target = self.steps.steps.as_ref()?;
                let result = step_with(&self.steps.service, target, request, self.owner.as_deref());
                // A bad request ends the stream with its status but leaves the sessions
                // usable (the client may retry on a new stream).
                if result.is_err() {
                    self.steps.finish(true);
                }
                Some(result)
            }
            // A request that does not parse: the client's error, like a bad action; its
            // sessions stay usable.
            Some(Err(status)) if status.code() == Code::InvalidArgument => {
                self.steps.finish(true);
                Some(Err(codec::in_stream(status)))
            }
            // Half-close, a reset stream, or an oversized request: the client is done
            // with this stream, and its sessions close with it.
            Some(Err(status)) => {
                self.steps.finish(false);
                Some(Err(status::oversize_as_resource_exhausted(status)))
            }
            None => {
                self.steps.finish(false);
                None
            }
        }
    }
}

type StepResponses = Pin<Box<dyn Stream<Item = Result<StepResponse, Status>> + Send>>;

#[tonic::async_trait]
impl EnvService for PyEnvService {
    async fn get_version(
        &self,
        request: Request<GetVersionRequest>,
    ) -> Result<Response<GetVersionResponse>, Status> {
        self.unary("GetVersion", request).await
    }

    async fn list_envs(
        &self,
        request: Request<ListEnvsRequest>,
    ) -> Result<Response<ListEnvsResponse>, Status> {
        self.unary("ListEnvs", request).await
    }

    async fn make(&self, request: Request<MakeRequest>) -> Result<Response<MakeResponse>, Status> {
        self.unary("Make", request).await
    }

    async fn reset(
        &self,
        request: Request<ResetRequest>,
    ) -> Result<Response<ResetResponse>, Status> {
        self.unary("Reset", request).await
    }

    async fn step(&self, request: Request<StepRequest>) -> Result<Response<StepResponse>, Status> {
        let owner = self.owner(&request)?;
        step_with(
            &self.service,
            &self.service,
            request.into_inner(),
            owner.as_deref(),
        )
        .map(Response::new)
    }

    type StepStreamStream = StepResponses;

    async fn step_stream(
        &self,
        request: Request<Streaming<StepRequest>>,
    ) -> Result<Response<Self::StepStreamStream>, Status> {
        let owner = self.owner(&request)?;
        let steps = Python::attach(|py| {
            self.service
                .bind(py)
                .call_method0("open_stream")
                .map(Bound::unbind)
                .map_err(|err| status::from_pyerr(py, &self.service, err))
        })?;
        let state = StreamState {
            inbound: request.into_inner(),
            steps: StreamSteps {
                service: Arc::clone(&self.service),
                steps: Some(steps),
            },
            busy_poll: self.busy_poll,
            owner,
        };
        let responses = futures::stream::unfold(state, |mut state| async move {
            let item = state.next().await?;
            Some((item, state))
        });
        Ok(Response::new(Box::pin(responses)))
    }

    async fn close_session(
        &self,
        request: Request<CloseRequest>,
    ) -> Result<Response<CloseResponse>, Status> {
        self.unary("CloseSession", request).await
    }

    async fn close(
        &self,
        request: Request<CloseRequest>,
    ) -> Result<Response<CloseResponse>, Status> {
        self.unary("Close", request).await
    }

    async fn render(
        &self,
        request: Request<RenderRequest>,
    ) -> Result<Response<RenderResponse>, Status> {
        self.unary("Render", request).await
    }
}
