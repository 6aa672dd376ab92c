//! Server discovery end to end: a real DNS server (hickory-server, an in-memory zone
//! on 127.0.0.1) answers one name with several loopback addresses, each with a real
//! env_server on the same port, as several hosts would be; and a `file:` list that a
//! launcher rewrites. Actors spread over the servers, a killed server's actors move
//! to the others, and the run goes on to its budget.

mod pki;

use std::net::{Ipv4Addr, SocketAddr};
use std::path::Path;
use std::sync::Arc;
use std::time::Duration;

use agent::env::connection::ConnectionConfig;
use agent::env::discovery::ServerAddress;
use agent::env::error::EnvError;
use agent::env::pool::ServerPool;
use agent::env::server_process::{LocalServer, ServerOptions};
use agent::runtime::train::{TrainOptions, TrainSummary, train};
use hickory_server::Server;
use hickory_server::net::runtime::TokioRuntimeProvider;
use hickory_server::proto::rr::rdata::{A, SOA};
use hickory_server::proto::rr::{LowerName, Name, RData, Record};
use hickory_server::store::in_memory::InMemoryZoneHandler;
use hickory_server::zone_handler::{AxfrPolicy, Catalog, ZoneType};
use integration_tests::smoke_config;

/// The name the DNS server answers.
const NAME: &str = "envs.test";

/// A DNS server for the zone `test.` with `envs.test` A records; stops when dropped.
struct Dns {
    address: SocketAddr,
    _server: Server<Catalog>,
}

impl Dns {
    /// Serve `NAME -> ips` over UDP and TCP on 127.0.0.1 (an OS-chosen port).
    async fn start(ips: &[Ipv4Addr]) -> Dns {
        let origin = Name::from_ascii("test.").unwrap();
        let mut zone = InMemoryZoneHandler::<TokioRuntimeProvider>::empty(
            origin.clone(),
            ZoneType::Primary,
            AxfrPolicy::Deny,
        );
        let soa = SOA::new(
            Name::from_ascii("ns.test.").unwrap(),
            Name::from_ascii("admin.test.").unwrap(),
            1,
            60,
            60,
            60,
            0,
        );
        assert!(zone.upsert_mut(Record::from_rdata(origin.clone(), 0, RData::SOA(soa)), 1));
        let name = Name::from_ascii(format!("{NAME}.")).unwrap();
        for &ip in ips {
            // TTL 0: every lookup asks again, as a re-resolve after a loss must.
            assert!(zone.upsert_mut(Record::from_rdata(name.clone(), 0, RData::A(A(ip))), 1));
        }
        let mut catalog = Catalog::new();
        catalog.upsert(LowerName::new(&origin), vec![Arc::new(zone)]);
        let mut server = Server::new(catalog);
        // UDP and TCP on the same port; another process may hold the TCP one.
        for _ in 0..10 {
            let udp = tokio::net::UdpSocket::bind("127.0.0.1:0").await.unwrap();
            let address = udp.local_addr().unwrap();
            let Ok(tcp) = tokio::net::TcpListener::bind(address).await else {
                continue;
            };
            server.register_socket(udp);
            server.register_listener(tcp, Duration::from_secs(5), 64);
            return Dns {
                address,
                _server: server,
            };
        }
        panic!("no free port for the DNS server");
    }
}

/// Real env_servers on `hosts`, all on one port (the first picks it; taken: try again).
async fn servers_on_one_port(hosts: &[&str]) -> (u16, Vec<LocalServer>) {
    'attempt: for _ in 0..5 {
        let mut started = Vec::new();
        let mut port = 0;
        for host in hosts {
            let options = ServerOptions {
                host: host.to_string(),
                port,
                ..ServerOptions::default()
            };
            match LocalServer::start(&options).await {
                Ok(server) => {
                    port = server.port();
                    started.push(server);
                }
                Err(_) if port != 0 => continue 'attempt, // the port is taken on this host
                Err(e) => panic!("env_server on {host} starts: {e}"),
            }
        }
        return (port, started);
    }
    panic!("no port free on all of {hosts:?}");
}

/// Env steps at the last finished episode in the run's episodes.csv (0 before one).
fn env_steps(runs: &Path) -> u64 {
    std::fs::read_dir(runs)
        .ok()
        .and_then(|mut d| d.next())
        .and_then(|e| std::fs::read_to_string(e.ok()?.path().join("episodes.csv")).ok())
        .and_then(|t| t.lines().skip(1).last()?.split(',').next()?.parse().ok())
        .unwrap_or(0)
}

/// Lines of the run's learner.jsonl (one per `log_period` learner steps).
fn learner_lines(runs: &Path) -> usize {
    std::fs::read_dir(runs)
        .ok()
        .and_then(|mut d| d.next())
        .and_then(|e| std::fs::read_to_string(e.ok()?.path().join("learner.jsonl")).ok())
        .map_or(0, |t| t.lines().count())
}

/// Wait until the run has done `steps` env steps (its learner has started by then).
async fn wait_for_steps(runs: &Path, steps: u64) {
    tokio::time::timeout(Duration::from_secs(120), async {
        while env_steps(runs) < steps {
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
    })
    .await
    .expect("training makes progress");
}

/// The actors that started on `address`, and checks every one of them moved off it.
fn moved_off(summary: &TrainSummary, address: &str) -> usize {
    let on: Vec<_> = summary
        .actor_servers
        .iter()
        .filter(|a| a.servers[0] == address)
        .collect();
    for a in &on {
        assert!(
            a.servers.len() >= 2 && a.servers.last().unwrap() != address,
            "actor {} stayed on the killed server: {:?}",
            a.actor,
            a.servers
        );
    }
    on.len()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn actors_spread_over_every_address_of_a_name_and_leave_a_killed_server() {
    let ips = [
        Ipv4Addr::new(127, 0, 0, 2),
        Ipv4Addr::new(127, 0, 0, 3),
        Ipv4Addr::new(127, 0, 0, 4),
    ];
    let hosts: Vec<String> = ips.iter().map(ToString::to_string).collect();
    let hosts: Vec<&str> = hosts.iter().map(String::as_str).collect();
    let (port, mut envs) = servers_on_one_port(&hosts).await;
    let dns = Dns::start(&ips).await;
    let spec = format!("dns://{}/{NAME}:{port}", dns.address);
    let address = |ip: &str| format!("{ip}:{port} ({NAME})");

    let runs = tempfile::tempdir().unwrap();
    let mut cfg = smoke_config(runs.path());
    cfg.run.total_env_steps = 6000;
    cfg.env.num_actors = 6;
    cfg.env.num_envs = 2;
    cfg.env.servers = vec![spec.clone()];
    cfg.validate().unwrap();
    let run = tokio::spawn(async move { train(cfg, &[spec], TrainOptions::default()).await });
    wait_for_steps(runs.path(), 2000).await;
    let learner_at_kill = learner_lines(runs.path());
    envs.remove(1).kill().await.unwrap();
    let summary = run.await.unwrap().expect("the run survives a lost server");

    // Each actor checks the budget before its step of B instances: a little overshoot.
    assert!(
        (6000..6000 + 6 * 2).contains(&summary.env_steps),
        "{}",
        summary.env_steps
    );
    assert!(
        learner_lines(runs.path()) > learner_at_kill,
        "the learner kept stepping after the kill"
    );
    let firsts: std::collections::BTreeSet<&str> = summary
        .actor_servers
        .iter()
        .map(|a| a.servers[0].as_str())
        .collect();
    let expected: std::collections::BTreeSet<String> = hosts.iter().map(|h| address(h)).collect();
    assert_eq!(
        firsts,
        expected.iter().map(String::as_str).collect(),
        "two actors per server"
    );
    assert_eq!(moved_off(&summary, &address("127.0.0.3")), 2);
    assert_eq!(summary.eval_episodes.len(), 2, "evaluated on a live server");
    for server in envs {
        server.stop().await.unwrap();
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_rewritten_file_moves_the_actors_of_a_killed_server() {
    let options = ServerOptions::default();
    let (first, second) = tokio::join!(LocalServer::start(&options), LocalServer::start(&options));
    let (first, second) = (first.unwrap(), second.unwrap());
    let dir = tempfile::tempdir().unwrap();
    let list = dir.path().join("servers.txt");
    std::fs::write(
        &list,
        format!("# written by the launcher\n{}\n", first.address()),
    )
    .unwrap();
    let spec = format!("file:{}", list.display());

    let runs = dir.path().join("runs");
    let mut cfg = smoke_config(&runs);
    cfg.run.total_env_steps = 4000;
    cfg.env.num_actors = 2;
    cfg.env.num_envs = 4;
    let run = {
        let spec = spec.clone();
        tokio::spawn(async move { train(cfg, &[spec], TrainOptions::default()).await })
    };
    wait_for_steps(&runs, 1500).await;
    // As a launcher would: the new list by temp file and rename, then the old server goes.
    let tmp = dir.path().join("servers.txt.tmp");
    std::fs::write(&tmp, format!("{}\n", second.address())).unwrap();
    std::fs::rename(&tmp, &list).unwrap();
    let first_address = first.address().to_string();
    first.kill().await.unwrap();
    let summary = run.await.unwrap().expect("the run survives a lost server");

    assert!(
        (4000..4000 + 2 * 4).contains(&summary.env_steps),
        "{}",
        summary.env_steps
    );
    for a in &summary.actor_servers {
        assert_eq!(
            a.servers,
            [first_address.clone(), second.address().to_string()],
            "actor {}",
            a.actor
        );
    }
    second.stop().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn resolved_addresses_keep_the_name_for_tls_and_bad_names_fail_clearly() {
    let dir = tempfile::tempdir().unwrap();
    // A certificate for the name only: a check against the IP dialled would fail.
    let pki = pki::write_pki(dir.path(), "disc", &[NAME]);
    let path = |p: &Path| p.display().to_string();
    let (ca, cert, key) = (path(&pki.ca), path(&pki.server_cert), path(&pki.server_key));
    let write = |name: &str, text: String| {
        let path = dir.path().join(name);
        std::fs::write(&path, text).unwrap();
        path.display().to_string()
    };
    let tokens = write("tokens", "learner:discovery-token-0123456789\n".into());
    let ips = [Ipv4Addr::new(127, 0, 0, 5), Ipv4Addr::new(127, 0, 0, 6)];
    let mut envs = Vec::new();
    let mut port = 0;
    for ip in ips {
        let options = ServerOptions {
            host: ip.to_string(),
            port,
            extra_args: [
                "--tls-cert",
                &cert,
                "--tls-key",
                &key,
                "--auth-token-file",
                &tokens,
            ]
            .map(String::from)
            .to_vec(),
            ..ServerOptions::default()
        };
        let server = LocalServer::start(&options)
            .await
            .expect("TLS env_server starts");
        port = server.port();
        envs.push(server);
    }
    let dns = Dns::start(&ips).await;
    let connection = ConnectionConfig {
        tls_ca_file: Some(ca.into()),
        token_file: Some(tokens.into()),
        ..ConnectionConfig::default()
    };
    let pool = ServerPool::connect(
        &[format!("dns://{}/{NAME}:{port}", dns.address)],
        &connection,
    )
    .await
    .expect("TLS to resolved addresses checks the name");
    let (a, b) = (pool.assign(0), pool.assign(1));
    assert_eq!(
        [a.address.clone(), b.address.clone()],
        ips.map(|ip| ServerAddress {
            dial: format!("{ip}:{port}"),
            tls_name: Some(NAME.into()),
        })
    );
    for assignment in [a, b] {
        assert!(!assignment.client.list_envs().await.unwrap().is_empty());
    }

    let err = ServerPool::connect(
        &[format!("dns://{}/nothing.test:{port}", dns.address)],
        &connection,
    )
    .await
    .unwrap_err();
    assert!(
        matches!(err, EnvError::Discovery(_))
            && err
                .to_string()
                .ends_with("expected nothing.test to resolve to at least one address, got no such name (NXDOMAIN)"),
        "{err}"
    );
    for server in envs {
        server.stop().await.unwrap();
    }
}
