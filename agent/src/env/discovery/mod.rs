//! Where the env servers are: the address forms `--server` and `env.servers` accept,
//! and the current addresses behind each.
//!
//! Three forms ([`ServerSource`]):
//! - a plain address, `host:port`, `http://host:port` or `https://host:port`: itself;
//! - `dns:NAME:PORT`, or gRPC's target syntax `dns://NAMESERVER/NAME:PORT` (an empty
//!   authority, `dns:///NAME:PORT`, means the system's resolver, `/etc/resolv.conf`):
//!   every A and AAAA record of NAME, each as `IP:PORT`, with NAME kept as the name
//!   the server's TLS certificate must carry;
//! - `file:PATH`: one plain address per line (blank lines and `#` comments skipped),
//!   read again on every resolve, so whoever starts servers (a launcher writing the
//!   file by temp file and rename) can change the set while a run goes on.
//!
//! Resolving says where servers are now; which actor goes where is
//! [`super::pool::ServerPool`]'s job.

use std::fmt;
use std::net::{IpAddr, SocketAddr};
use std::path::PathBuf;

mod resolve;

use resolve::{lookup, read_list};

/// The errors of this module live in [`crate::env::error`], beside the other env errors
/// that wrap them, so that `error` depends on nothing above it.
pub use crate::env::error::DiscoveryError;

/// The forms a server address may take, for error messages.
pub const FORMS: &str = "host:port, http://host:port, https://host:port, dns:NAME:PORT, \
                         dns://NAMESERVER_IP[:PORT]/NAME:PORT or file:PATH";

/// Port of a name server given without one.
const DNS_PORT: u16 = 53;

/// One server to connect to: what the channel dials, and the name TLS checks.
#[derive(Debug, Clone, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct ServerAddress {
    /// `host:port`, `http://…` or `https://…`; for a `dns:` name, the IP found and the port.
    pub dial: String,
    /// The name the server's certificate must carry when `dial` holds an IP found
    /// under it (the `dns:` name); `None`: `dial`'s own host.
    pub tls_name: Option<String>,
}

impl ServerAddress {
    /// An address dialled as given.
    pub fn plain(dial: impl Into<String>) -> Self {
        Self {
            dial: dial.into(),
            tls_name: None,
        }
    }
}

impl fmt::Display for ServerAddress {
    /// `127.0.0.2:50051 (envs.example)` for a resolved name, else the address itself.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match &self.tls_name {
            Some(name) => write!(f, "{} ({name})", self.dial),
            None => f.write_str(&self.dial),
        }
    }
}

/// A DNS name whose A and AAAA records are the servers.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DnsTarget {
    /// The name looked up (also the TLS server name).
    pub name: String,
    /// The servers' port.
    pub port: u16,
    /// The name server to ask; `None`: the system's resolver configuration.
    pub nameserver: Option<SocketAddr>,
}

/// Where a set of servers is found (one `--server` / `env.servers` entry).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ServerSource {
    /// One address, dialled as given.
    Static(String),
    /// Every address behind a DNS name.
    Dns(DnsTarget),
    /// The addresses listed in a file, one per line.
    File(PathBuf),
}

impl ServerSource {
    /// Read one address entry (see the module docs for the forms).
    pub fn parse(spec: &str) -> Result<Self, DiscoveryError> {
        let bad = |expected: &str, got: String| DiscoveryError::Syntax {
            spec: spec.to_string(),
            expected: expected.to_string(),
            got,
        };
        let text = spec.trim();
        if text.is_empty() {
            return Err(bad(FORMS, "an empty address".into()));
        }
        if let Some(rest) = text.strip_prefix("dns://") {
            let (authority, target) = rest.split_once('/').ok_or_else(|| {
                bad(
                    "dns://NAMESERVER/NAME:PORT (a '/' after the name server)",
                    "no '/'".into(),
                )
            })?;
            let nameserver = if authority.is_empty() {
                None
            } else {
                Some(parse_nameserver(authority).ok_or_else(|| {
                    bad(
                        "a name server IP[:PORT] after dns:// (e.g. 127.0.0.1:8600), or none (dns:///NAME:PORT)",
                        format!("{authority:?}"),
                    )
                })?)
            };
            return parse_dns_target(target, nameserver).map_err(|(e, g)| bad(e, g));
        }
        if let Some(target) = text.strip_prefix("dns:") {
            return parse_dns_target(target, None).map_err(|(e, g)| bad(e, g));
        }
        if let Some(path) = text.strip_prefix("file:") {
            if path.is_empty() {
                return Err(bad("file:PATH", "no path".into()));
            }
            return Ok(ServerSource::File(PathBuf::from(path)));
        }
        parse_plain(text).map_err(|got| bad(FORMS, got))?;
        Ok(ServerSource::Static(text.to_string()))
    }

    /// Whether the addresses can change while a run goes on (`dns:` and `file:`).
    pub fn is_dynamic(&self) -> bool {
        !matches!(self, ServerSource::Static(_))
    }

    /// The addresses behind this source now. `spec` is the entry as given (for errors).
    pub async fn resolve(&self, spec: &str) -> Result<Vec<ServerAddress>, DiscoveryError> {
        match self {
            ServerSource::Static(address) => Ok(vec![ServerAddress::plain(address.clone())]),
            ServerSource::Dns(target) => lookup(spec, target).await,
            ServerSource::File(path) => read_list(spec, path),
        }
    }
}

/// `IP`, `IP:PORT`, `[IPv6]` or `[IPv6]:PORT`.
fn parse_nameserver(text: &str) -> Option<SocketAddr> {
    if let Ok(address) = text.parse::<SocketAddr>() {
        return Some(address);
    }
    let ip = text.strip_prefix('[').and_then(|t| t.strip_suffix(']'));
    ip.unwrap_or(text)
        .parse::<IpAddr>()
        .ok()
        .map(|ip| SocketAddr::new(ip, DNS_PORT))
}

/// `NAME:PORT` of a `dns:` form; on error, what was expected and what was found.
fn parse_dns_target(
    text: &str,
    nameserver: Option<SocketAddr>,
) -> Result<ServerSource, (&'static str, String)> {
    const EXPECTED: &str = "dns:NAME:PORT or dns://NAMESERVER/NAME:PORT (a DNS name and a port)";
    let (name, port) = text
        .rsplit_once(':')
        .ok_or((EXPECTED, format!("no port in {text:?}")))?;
    let port: u16 = port
        .parse()
        .ok()
        .filter(|&p| p != 0)
        .ok_or((EXPECTED, format!("port {port:?}")))?;
    let valid_name = !name.is_empty()
        && name
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'-' | b'.' | b'_'));
    if !valid_name {
        return Err((EXPECTED, format!("name {name:?}")));
    }
    Ok(ServerSource::Dns(DnsTarget {
        name: name.to_string(),
        port,
        nameserver,
    }))
}

/// A plain address: `host:port`, or an `http(s)://` URL; on error, what was found.
pub(super) fn parse_plain(text: &str) -> Result<(), String> {
    let rest = match text.split_once("://") {
        Some(("http" | "https", rest)) => rest,
        Some((scheme, _)) => return Err(format!("scheme {scheme:?}")),
        None => text,
    };
    if rest.is_empty() || rest.chars().any(char::is_whitespace) {
        return Err(format!("{text:?}"));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn err(spec: &str) -> String {
        ServerSource::parse(spec).unwrap_err().to_string()
    }

    #[test]
    fn every_form_parses() {
        let dns = |name: &str, port, nameserver: Option<&str>| {
            ServerSource::Dns(DnsTarget {
                name: name.into(),
                port,
                nameserver: nameserver.map(|n| n.parse().unwrap()),
            })
        };
        let cases = [
            (
                "localhost:50051",
                ServerSource::Static("localhost:50051".into()),
            ),
            (
                "https://envs.example:443",
                ServerSource::Static("https://envs.example:443".into()),
            ),
            ("dns:envs.example:50051", dns("envs.example", 50051, None)),
            ("dns:///envs.example:7", dns("envs.example", 7, None)),
            (
                "dns://127.0.0.1:5353/envs.example:50051",
                dns("envs.example", 50051, Some("127.0.0.1:5353")),
            ),
            (
                "dns://10.0.0.2/envs.example:50051",
                dns("envs.example", 50051, Some("10.0.0.2:53")),
            ),
            (
                "dns://[::1]:8600/envs.service.consul:1",
                dns("envs.service.consul", 1, Some("[::1]:8600")),
            ),
            (
                "file:/tmp/servers.txt",
                ServerSource::File("/tmp/servers.txt".into()),
            ),
        ];
        for (spec, expected) in cases {
            assert_eq!(ServerSource::parse(spec).unwrap(), expected, "{spec}");
        }
        assert!(!ServerSource::parse("h:1").unwrap().is_dynamic());
        assert!(ServerSource::parse("file:x").unwrap().is_dynamic());
    }

    #[test]
    fn malformed_forms_say_what_was_expected_and_what_arrived() {
        assert_eq!(
            err("dns:envs.example"),
            "server address \"dns:envs.example\": expected dns:NAME:PORT or \
             dns://NAMESERVER/NAME:PORT (a DNS name and a port), got no port in \"envs.example\""
        );
        assert!(err("dns:envs.example:http").contains("got port \"http\""));
        assert!(err("dns:envs.example:0").contains("got port \"0\""));
        assert!(err("dns::50051").contains("got name \"\""));
        assert!(err("dns:a/b:1").contains("got name \"a/b\""));
        assert!(err("dns://consul.local/envs:1").contains("got \"consul.local\""));
        assert!(err("dns://127.0.0.1:8600").contains("got no '/'"));
        assert!(err("file:").contains("expected file:PATH, got no path"));
        assert!(err("consul://envs:1").contains("got scheme \"consul\""));
        assert!(err("  ").contains("got an empty address"));
    }

    #[tokio::test]
    async fn a_file_lists_addresses_and_is_read_on_every_resolve() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("servers.txt");
        let spec = format!("file:{}", path.display());
        let source = ServerSource::parse(&spec).unwrap();
        let e = source.resolve(&spec).await.unwrap_err().to_string();
        assert!(
            e.contains("expected a readable UTF-8 file of server addresses"),
            "{e}"
        );
        std::fs::write(
            &path,
            "# launcher\n\n127.0.0.2:1\n  https://b.example:2  \n127.0.0.2:1\n",
        )
        .unwrap();
        let got = source.resolve(&spec).await.unwrap();
        assert_eq!(
            got,
            [
                ServerAddress::plain("127.0.0.2:1"),
                ServerAddress::plain("https://b.example:2")
            ]
        );
        std::fs::write(&path, "# nothing yet\n").unwrap();
        let e = source.resolve(&spec).await.unwrap_err().to_string();
        assert!(
            e.contains("expected at least one address line, got none in"),
            "{e}"
        );
        std::fs::write(&path, "h:1\ndns:x:1\n").unwrap();
        let e = source.resolve(&spec).await.unwrap_err().to_string();
        assert!(e.contains("got \"dns:x:1\" on line 2"), "{e}");
    }

    #[test]
    fn a_resolved_address_shows_its_name() {
        let a = ServerAddress {
            dial: "127.0.0.2:9".into(),
            tls_name: Some("envs.test".into()),
        };
        assert_eq!(a.to_string(), "127.0.0.2:9 (envs.test)");
        assert_eq!(ServerAddress::plain("h:1").to_string(), "h:1");
    }
}
