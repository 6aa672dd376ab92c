//! How the agent reaches env servers on other hosts: TLS and a bearer token.
//!
//! [`ConnectionConfig`] names the files (the run config's `[env.connection]`, or the
//! CLI's `--tls-ca`, `--tls-client-cert`, `--tls-client-key` and `--token-file`);
//! [`Credentials`] is what they hold, read once when the agent connects. One
//! connection setting applies to every server of a run.

use std::fmt;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::core::learner_config::ConfigError;
use crate::env::error::EnvError;

/// Files that secure the connections to the servers (env_server's `--tls-cert`,
/// `--tls-client-ca` and `--auth-token-file` on the other side).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ConnectionConfig {
    /// PEM file of the CA that signed the servers' certificates. Set: every server is
    /// reached over TLS and must present a certificate this CA signed. Unset: TLS only
    /// for `https://` servers, checked against the system's trusted roots.
    pub tls_ca_file: Option<PathBuf>,
    /// PEM certificate the agent presents to servers started with `--tls-client-ca`
    /// (mutual TLS); needs `tls_client_key_file`.
    pub tls_client_cert_file: Option<PathBuf>,
    /// PEM private key of `tls_client_cert_file`.
    pub tls_client_key_file: Option<PathBuf>,
    /// File with the bearer token, one line (`token`, or `name:token` as in the
    /// server's `--auth-token-file`), sent as `authorization: Bearer <token>` on every
    /// call. Kept in a file so that configs and logs never hold it.
    pub token_file: Option<PathBuf>,
}

impl ConnectionConfig {
    /// Nothing set: plain connections without a token.
    pub fn is_empty(&self) -> bool {
        *self == Self::default()
    }

    /// The client certificate and key come together.
    pub fn validate(&self) -> Result<(), ConfigError> {
        match (&self.tls_client_cert_file, &self.tls_client_key_file) {
            (Some(_), None) | (None, Some(_)) => Err(ConfigError::Invalid {
                field: "env.connection.tls_client_cert_file / tls_client_key_file".into(),
                requirement: "both set or both unset".into(),
                got: format!(
                    "cert {:?}, key {:?}",
                    self.tls_client_cert_file, self.tls_client_key_file
                ),
            }),
            _ => Ok(()),
        }
    }

    /// Read the files.
    pub fn load(&self) -> Result<Credentials, EnvError> {
        let ca = self
            .tls_ca_file
            .as_deref()
            .map(|p| read_pem("tls_ca_file", p, "CERTIFICATE"))
            .transpose()?;
        let client = match (&self.tls_client_cert_file, &self.tls_client_key_file) {
            (Some(cert), Some(key)) => Some(ClientIdentity {
                cert_pem: read_pem("tls_client_cert_file", cert, "CERTIFICATE")?,
                key_pem: read_pem("tls_client_key_file", key, "PRIVATE KEY")?,
            }),
            _ => None,
        };
        let token = self.token_file.as_deref().map(read_token).transpose()?;
        Ok(Credentials {
            tls_ca_pem: ca,
            client,
            token,
        })
    }
}

/// A certificate and key the agent presents (mutual TLS).
#[derive(Clone)]
pub struct ClientIdentity {
    /// PEM certificate chain.
    pub cert_pem: Vec<u8>,
    /// PEM private key.
    pub key_pem: Vec<u8>,
}

/// What a connection presents, read from a [`ConnectionConfig`]'s files.
#[derive(Clone, Default)]
pub struct Credentials {
    /// PEM of the CA the servers' certificates must chain to (None: system roots).
    pub tls_ca_pem: Option<Vec<u8>>,
    /// Client certificate for mutual TLS.
    pub client: Option<ClientIdentity>,
    /// Bearer token.
    pub token: Option<String>,
}

impl Credentials {
    /// Whether a server address without a scheme is reached over TLS: when a CA or a
    /// client certificate is given (`https://` always is, `http://` never).
    pub fn implies_tls(&self) -> bool {
        self.tls_ca_pem.is_some() || self.client.is_some()
    }
}

impl fmt::Debug for Credentials {
    /// Says what is set, never the token or the key.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Credentials")
            .field("tls_ca", &self.tls_ca_pem.is_some())
            .field("client_certificate", &self.client.is_some())
            .field("token", &self.token.as_ref().map(|_| "<redacted>"))
            .finish()
    }
}

fn read_file(field: &'static str, path: &Path) -> Result<Vec<u8>, EnvError> {
    std::fs::read(path).map_err(|e| EnvError::Credentials {
        field,
        path: path.to_path_buf(),
        reason: format!("expected a readable file, got: {e}"),
    })
}

/// A PEM file's bytes, checked for a block of `kind` so a swapped file fails here.
fn read_pem(field: &'static str, path: &Path, kind: &str) -> Result<Vec<u8>, EnvError> {
    let data = read_file(field, path)?;
    let marker = format!("{kind}-----");
    if !data.windows(marker.len()).any(|w| w == marker.as_bytes()) {
        return Err(EnvError::Credentials {
            field,
            path: path.to_path_buf(),
            reason: format!("expected a PEM file with a '{kind}' block, got none"),
        });
    }
    Ok(data)
}

/// The one token line of a token file (blank and `#` lines skipped; a `name:` prefix
/// dropped), as env_server's `security.parse_token_lines` reads it.
fn read_token(path: &Path) -> Result<String, EnvError> {
    let bad = |reason: String| EnvError::Credentials {
        field: "token_file",
        path: path.to_path_buf(),
        reason,
    };
    let text = String::from_utf8(read_file("token_file", path)?)
        .map_err(|_| bad("expected UTF-8 text, got other bytes".into()))?;
    let lines: Vec<&str> = text
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with('#'))
        .collect();
    let [line] = lines[..] else {
        return Err(bad(format!(
            "expected exactly one token line, got {}",
            lines.len()
        )));
    };
    let token = line.rsplit_once(':').map_or(line, |(_, token)| token);
    if token.is_empty() || !token.bytes().all(|b| b.is_ascii_graphic()) {
        return Err(bad(format!(
            "expected a token of printable ASCII characters without spaces, got one of {} characters",
            token.chars().count()
        )));
    }
    Ok(token.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_token_file_gives_its_one_token_without_the_name() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("token");
        std::fs::write(&path, "# for host a\n\nalice:s3cret-token-0123456789\n").unwrap();
        assert_eq!(read_token(&path).unwrap(), "s3cret-token-0123456789");
        std::fs::write(&path, "a-token-without-name-01\nsecond-token-0123456\n").unwrap();
        let err = read_token(&path).unwrap_err().to_string();
        assert!(
            err.contains("expected exactly one token line, got 2"),
            "{err}"
        );
        assert!(
            !err.contains("second-token"),
            "the error must not quote a token: {err}"
        );
    }

    #[test]
    fn a_client_certificate_needs_its_key_and_debug_hides_the_token() {
        let cfg = ConnectionConfig {
            tls_client_cert_file: Some("client.pem".into()),
            ..ConnectionConfig::default()
        };
        let err = cfg.validate().unwrap_err().to_string();
        assert!(err.contains("both set or both unset"), "{err}");
        let creds = Credentials {
            token: Some("do-not-print-0123456789".into()),
            ..Credentials::default()
        };
        assert!(!format!("{creds:?}").contains("do-not-print"));
    }
}
