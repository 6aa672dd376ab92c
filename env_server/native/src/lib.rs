//! env_server's native gRPC front: a tonic server on its own thread inside the Python
//! server process. It replaces grpc.aio as the transport and nothing else: every RPC
//! is answered by the Python `env_server.service.EnvService` it is given.
//!
//! Why it exists: grpc.aio hands each message from its I/O thread to a poller thread
//! and then to the asyncio loop, which costs about 0.2 ms per streamed Step on a small
//! machine (the issue-2 B=1 overhead target is 0.3 ms in all). Here the thread that
//! reads a StepRequest off the socket calls `Session.step` itself (under the GIL) and
//! writes the reply: no thread hop on the Step path. Unary RPCs other than Step are
//! queued onto the Python asyncio loop, exactly where grpc.aio ran them.
//!
//! The Python contract (`env_server/service.py` implements it):
//! - `step(session_id, dtype, shape, data, owner) -> bytes` (a serialized StepResponse;
//!   `owner` is the caller's client name, None without tokens);
//! - `open_stream()` -> object with the same `step` and `finish(aborted: bool)`;
//! - `submit(method, request: bytes, reply: Reply, owner) -> concurrent.futures.Future`;
//! - `status_of(exc) -> (code_name, message)`, the one exception -> status mapping.

mod auth;
mod service;
mod status;

use std::net::TcpListener as StdTcpListener;
use std::sync::Mutex;
use std::thread::JoinHandle;
use std::time::Duration;

use mo_env_proto::v1::env_service_server::EnvServiceServer;
use pyo3::exceptions::{PyOSError, PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use tokio::sync::oneshot;
use tonic::transport::server::TcpIncoming;
use tonic::transport::{Certificate, Identity, ServerTlsConfig};

use auth::Tokens;

use service::PyEnvService;
pub use service::Reply;

/// gRPC service name, as registered with the health service.
const SERVICE_NAME: &str = "mo_env.v1.EnvService";

/// PEM bytes of the certificate chain, its private key, and the CA of client
/// certificates (None: no client certificates asked for).
type PemTls = (Vec<u8>, Vec<u8>, Option<Vec<u8>>);

/// A running native front; `stop()` ends it (and so does dropping it).
#[pyclass(frozen, module = "env_server_native")]
pub struct NativeFront {
    port: u16,
    stop_tx: Mutex<Option<oneshot::Sender<Duration>>>,
    thread: Mutex<Option<JoinHandle<()>>>,
}

#[pymethods]
impl NativeFront {
    /// Bind `host:port` (port 0: the OS picks) and start serving `service` on a new thread.
    /// `busy_poll_us` > 0: a StepStream waits that long for its next request without sleeping.
    /// `tls`: PEM (certificate chain, private key, client CA or None for no client
    /// certificates). `tokens`: `(client name, token)` pairs every EnvService call must
    /// present one of (`security.Tokens.entries`); None: no check.
    #[new]
    #[pyo3(signature = (service, host, port, max_message_bytes, busy_poll_us = 0, tls = None, tokens = None))]
    fn new(
        service: Py<PyAny>,
        host: &str,
        port: u16,
        max_message_bytes: usize,
        busy_poll_us: u64,
        tls: Option<PemTls>,
        tokens: Option<Vec<(String, String)>>,
    ) -> PyResult<Self> {
        let busy_poll = (busy_poll_us > 0).then(|| Duration::from_micros(busy_poll_us));
        let mut builder = tonic::transport::Server::builder();
        if let Some((cert, key, client_ca)) = tls {
            let mut config = ServerTlsConfig::new().identity(Identity::from_pem(cert, key));
            if let Some(ca) = client_ca {
                config = config.client_ca_root(Certificate::from_pem(ca));
            }
            // Parses the PEM now, so a bad file fails the server's start, not its thread.
            builder = builder.tls_config(config).map_err(|e| {
                PyValueError::new_err(format!(
                    "TLS: expected a certificate chain and its private key in PEM, got files that do not load: {e}"
                ))
            })?;
        }
        let front = Front {
            builder,
            busy_poll,
            tokens: tokens.map(Tokens::new),
        };
        let listener = StdTcpListener::bind((host, port))
            .map_err(|e| PyOSError::new_err(format!("could not bind {host}:{port}: {e}")))?;
        let port = listener.local_addr()?.port();
        listener.set_nonblocking(true)?;
        let (stop_tx, stop_rx) = oneshot::channel();
        // One thread runs both the socket I/O and the handlers, so a Step is read,
        // computed and answered without waking another thread.
        let runtime = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .map_err(|e| {
                PyRuntimeError::new_err(format!("could not start the tokio runtime: {e}"))
            })?;
        let thread = std::thread::Builder::new()
            .name("env_server_native".into())
            .spawn(move || {
                serve(
                    runtime,
                    listener,
                    service,
                    max_message_bytes,
                    front,
                    stop_rx,
                )
            })
            .map_err(|e| {
                PyRuntimeError::new_err(format!("could not start the front thread: {e}"))
            })?;
        Ok(Self {
            port,
            stop_tx: Mutex::new(Some(stop_tx)),
            thread: Mutex::new(Some(thread)),
        })
    }

    /// The bound port.
    #[getter]
    fn port(&self) -> u16 {
        self.port
    }

    /// Report NOT_SERVING, let calls in flight finish for up to `grace_seconds`, then stop.
    fn stop(&self, py: Python<'_>, grace_seconds: f64) {
        let grace = Duration::from_secs_f64(grace_seconds.max(0.0));
        if let Some(tx) = self.stop_tx.lock().expect("stop_tx poisoned").take() {
            let _ = tx.send(grace);
        }
        let thread = self.thread.lock().expect("thread poisoned").take();
        // Handlers on the front thread may be waiting for the GIL this thread holds.
        py.detach(|| {
            if let Some(thread) = thread {
                let _ = thread.join();
            }
        });
    }
}

impl Drop for NativeFront {
    fn drop(&mut self) {
        if let Some(tx) = self.stop_tx.get_mut().ok().and_then(Option::take) {
            let _ = tx.send(Duration::ZERO);
        }
    }
}

type OversizeRewrite = fn(http::Response<tonic::body::Body>) -> http::Response<tonic::body::Body>;

/// How the front serves, beyond where.
struct Front {
    /// The server builder, with its TLS acceptor when serving TLS.
    builder: tonic::transport::Server,
    busy_poll: Option<Duration>,
    tokens: Option<Tokens>,
}

/// The front thread: serve until told to stop, then give in-flight calls `grace`.
fn serve(
    runtime: tokio::runtime::Runtime,
    listener: StdTcpListener,
    service: Py<PyAny>,
    max_message_bytes: usize,
    front: Front,
    stop_rx: oneshot::Receiver<Duration>,
) {
    runtime.block_on(async move {
        let listener = match tokio::net::TcpListener::from_std(listener) {
            Ok(listener) => listener,
            Err(e) => {
                eprintln!("env_server_native: could not register the listener: {e}");
                return;
            }
        };
        let incoming = TcpIncoming::from(listener).with_nodelay(Some(true));
        let (health, health_service) = tonic_health::server::health_reporter();
        for name in ["", SERVICE_NAME] {
            health
                .set_service_status(name, tonic_health::ServingStatus::Serving)
                .await;
        }
        let env_service =
            EnvServiceServer::new(PyEnvService::new(service, front.busy_poll, front.tokens))
                .max_decoding_message_size(max_message_bytes)
                .max_encoding_message_size(max_message_bytes);
        let (grace_tx, grace_rx) = oneshot::channel();
        let shutdown = async move {
            let grace = stop_rx.await.unwrap_or(Duration::ZERO);
            for name in ["", SERVICE_NAME] {
                health
                    .set_service_status(name, tonic_health::ServingStatus::NotServing)
                    .await;
            }
            let _ = grace_tx.send(grace);
        };
        let builder = front.builder;
        let server = builder
            .layer(tower::util::MapResponseLayer::new(
                status::oversize_response as OversizeRewrite,
            ))
            .add_service(health_service)
            .add_service(env_service)
            .serve_with_incoming_shutdown(incoming, shutdown);
        // Graceful shutdown waits for every open stream; a client that keeps its
        // StepStream open must not keep the server alive past the grace period.
        let deadline = async move {
            let grace = grace_rx.await.unwrap_or(Duration::ZERO);
            tokio::time::sleep(grace).await;
        };
        tokio::select! {
            result = server => if let Err(e) = result {
                eprintln!("env_server_native: server error: {e}");
            },
            () = deadline => {}
        }
    });
    runtime.shutdown_timeout(Duration::from_millis(100));
}

/// The `env_server_native` Python module.
#[pymodule]
fn env_server_native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<NativeFront>()?;
    m.add_class::<Reply>()?;
    Ok(())
}
