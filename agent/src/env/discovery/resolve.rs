//! Asking where the servers are now: a `dns:` name's A and AAAA records (hickory, no
//! cache) and a `file:` list read afresh. The forms themselves are parsed in `mod.rs`.

use std::net::SocketAddr;
use std::path::Path;
use std::time::Duration;

use hickory_resolver::TokioResolver;
use hickory_resolver::config::{
    ConnectionConfig as DnsConnection, NameServerConfig, ResolverConfig,
};
use hickory_resolver::net::runtime::TokioRuntimeProvider;

use super::{DiscoveryError, DnsTarget, ServerAddress, parse_plain};

/// Every A and AAAA record of the target's name, asked afresh (no cache: this runs
/// when a server was lost, and the answer must be today's).
pub(super) async fn lookup(
    spec: &str,
    target: &DnsTarget,
) -> Result<Vec<ServerAddress>, DiscoveryError> {
    let failed = |reason: String| DiscoveryError::Lookup {
        spec: spec.to_string(),
        name: target.name.clone(),
        reason,
    };
    let mut builder = match target.nameserver {
        Some(server) => {
            let mut udp = DnsConnection::udp();
            udp.port = server.port();
            let mut tcp = DnsConnection::tcp();
            tcp.port = server.port();
            let config = ResolverConfig::from_name_servers(vec![NameServerConfig::new(
                server.ip(),
                true,
                vec![udp, tcp],
            )]);
            TokioResolver::builder_with_config(config, TokioRuntimeProvider::default())
        }
        None => TokioResolver::builder_tokio()
            .map_err(|e| failed(format!("no system resolver configuration: {e}")))?,
    };
    let options = builder.options_mut();
    options.ip_strategy = hickory_resolver::config::LookupIpStrategy::Ipv4AndIpv6;
    options.timeout = Duration::from_secs(2);
    options.attempts = 2;
    let resolver = builder
        .build()
        .map_err(|e| failed(format!("a resolver that cannot start: {e}")))?;
    let found = resolver
        .lookup_ip(target.name.as_str())
        .await
        .map_err(|e| {
            failed(if e.is_nx_domain() {
                "no such name (NXDOMAIN)".into()
            } else if e.is_no_records_found() {
                "no A or AAAA records".into()
            } else {
                e.to_string()
            })
        })?;
    let mut addresses: Vec<ServerAddress> = found
        .iter()
        .map(|ip| ServerAddress {
            dial: SocketAddr::new(ip, target.port).to_string(),
            tls_name: Some(target.name.clone()),
        })
        .collect();
    addresses.sort();
    addresses.dedup();
    if addresses.is_empty() {
        return Err(failed("no A or AAAA records".into()));
    }
    Ok(addresses)
}

/// The plain addresses listed in `path`, in file order.
pub(super) fn read_list(spec: &str, path: &Path) -> Result<Vec<ServerAddress>, DiscoveryError> {
    let failed = |expected: &str, got: String| DiscoveryError::File {
        spec: spec.to_string(),
        expected: expected.to_string(),
        got,
    };
    const EXPECTED: &str = "a readable UTF-8 file of server addresses, one per line";
    // A small file read rarely (at start and when a server is lost): blocking is fine.
    let text = std::fs::read_to_string(path)
        .map_err(|e| failed(EXPECTED, format!("{}: {e}", path.display())))?;
    let mut addresses = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        if line.starts_with("dns:") || line.starts_with("file:") {
            return Err(failed(
                "host:port, http://host:port or https://host:port on every line",
                format!("{line:?} on line {} of {}", i + 1, path.display()),
            ));
        }
        parse_plain(line).map_err(|got| {
            failed(
                "host:port, http://host:port or https://host:port on every line",
                format!("{got} on line {} of {}", i + 1, path.display()),
            )
        })?;
        let address = ServerAddress::plain(line);
        if !addresses.contains(&address) {
            addresses.push(address);
        }
    }
    if addresses.is_empty() {
        return Err(failed(
            "at least one address line",
            format!("none in {}", path.display()),
        ));
    }
    Ok(addresses)
}
