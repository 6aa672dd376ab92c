//! The channel under [`super::EnvClient`]: plain or TLS, and a bearer token on every call.

use std::time::Duration;

use mo_env_proto::v1::env_service_client::EnvServiceClient;
use tonic::metadata::{Ascii, MetadataValue};
use tonic::service::Interceptor;
use tonic::service::interceptor::InterceptedService;
use tonic::transport::{Certificate, Channel, ClientTlsConfig, Endpoint, Identity};

use crate::env::connection::Credentials;

/// The generated client over a channel that adds the token.
pub(super) type Stub = EnvServiceClient<InterceptedService<Channel, Bearer>>;

/// Adds `authorization: Bearer <token>` to every call when there is a token.
#[derive(Clone)]
pub(super) struct Bearer(Option<MetadataValue<Ascii>>);

impl Bearer {
    pub(super) fn new(token: Option<&str>) -> Result<Self, String> {
        token
            .map(|t| {
                let mut value = MetadataValue::try_from(format!("Bearer {t}"))
                    .map_err(|_| "the token is not valid in a gRPC header".to_string())?;
                // Keeps the token out of HPACK's shared table.
                value.set_sensitive(true);
                Ok(value)
            })
            .transpose()
            .map(Self)
    }
}

impl Interceptor for Bearer {
    fn call(
        &mut self,
        mut request: tonic::Request<()>,
    ) -> Result<tonic::Request<()>, tonic::Status> {
        if let Some(value) = &self.0 {
            request
                .metadata_mut()
                .insert("authorization", value.clone());
        }
        Ok(request)
    }
}

impl std::fmt::Debug for Bearer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let token = self.0.as_ref().map(|_| "<redacted>");
        f.debug_tuple("Bearer").field(&token).finish()
    }
}

/// The endpoint for `address` (`host:port`, `http://` or `https://`): TLS for
/// `https://`, and for a bare `host:port` when the credentials carry a CA or a client
/// certificate. `tls_name` is the name the certificate must carry when it is not
/// `address`'s host (a `dns:` name whose IP `address` holds).
pub(super) fn endpoint(
    address: &str,
    tls_name: Option<&str>,
    credentials: &Credentials,
) -> Result<Endpoint, String> {
    let tls = if let Some(rest) = address.strip_prefix("http://") {
        if credentials.implies_tls() {
            return Err(format!(
                "expected https://{rest} or {rest} with a TLS CA or client certificate set, got http://"
            ));
        }
        false
    } else {
        address.starts_with("https://") || credentials.implies_tls()
    };
    let uri = match (address.contains("://"), tls) {
        (true, _) => address.to_string(),
        (false, true) => format!("https://{address}"),
        (false, false) => format!("http://{address}"),
    };
    let mut endpoint = Endpoint::from_shared(uri)
        .map_err(|e| format!("invalid address: {e}"))?
        .tcp_nodelay(true)
        .connect_timeout(Duration::from_secs(5));
    if tls {
        let mut config = ClientTlsConfig::new();
        config = match &credentials.tls_ca_pem {
            Some(ca) => config.ca_certificate(Certificate::from_pem(ca)),
            None => config.with_native_roots(),
        };
        if let Some(client) = &credentials.client {
            config = config.identity(Identity::from_pem(&client.cert_pem, &client.key_pem));
        }
        if let Some(name) = tls_name {
            // Checked against the certificate and sent as SNI instead of the IP dialled.
            config = config.domain_name(name);
        }
        endpoint = endpoint
            .tls_config(config)
            .map_err(|e| format!("TLS settings: {e}"))?;
    }
    Ok(endpoint)
}

/// A connect error that retrying cannot fix: rustls rejected the handshake (a
/// certificate the CA did not sign or a name it does not cover, "invalid peer
/// certificate"; a plaintext server, "received corrupt message"; an alert from the
/// server, e.g. that it requires a client certificate), as opposed to a server that is
/// not listening yet. rustls's error type is not re-exported by tonic, so its messages
/// are matched.
pub(super) fn is_permanent(error: &tonic::transport::Error) -> bool {
    rejected_by_tls(error)
}

/// Whether `error` or one of its sources is a rustls rejection (see [`is_permanent`]).
/// Under mutual TLS a server refuses a missing client certificate after the TLS 1.3
/// handshake, so that rejection arrives with the first call, as its status's source.
pub(super) fn rejected_by_tls(error: &(dyn std::error::Error + 'static)) -> bool {
    const RUSTLS: [&str; 4] = [
        "invalid peer certificate",
        "received corrupt message",
        "received fatal alert",
        "peer is incompatible",
    ];
    let mut source = Some(error);
    while let Some(e) = source {
        let text = e.to_string();
        if RUSTLS.iter().any(|needle| text.contains(needle)) {
            return true;
        }
        source = e.source();
    }
    false
}
