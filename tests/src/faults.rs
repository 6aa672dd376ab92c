//! A training run with faults injected between the agent and a real env_server, and
//! the checks every such run must pass: the budget reached with exact counters, every
//! log row once, no session left on the server (`tests/faults.rs`, and the chaos soak).

use std::future::Future;
use std::path::Path;
use std::pin::pin;
use std::time::{Duration, Instant};

use agent::env::Env;
use agent::env::MakeOptions;
use agent::env::deadline::DeadlineConfig;
use agent::env::error::StatusKind;
use agent::env::grpc::EnvClient;
use agent::env::server_process::LocalServer;
use agent::runtime::checkpoint::run::latest_checkpoint;
use agent::runtime::run_config::TrainConfig;
use agent::runtime::train::TrainSummary;

use crate::proxy::{Direction, Fault, FaultProxy};

/// Sessions the test server allows at once: the check for sessions left behind makes
/// this many, which succeeds only when the run left none open.
pub const MAX_SESSIONS: usize = 16;

/// The deadlines of a faulted run: short, so that a blackhole costs seconds, not the
/// default's ten; still hundreds of times a DST step, and a Make of DST.
pub fn test_deadlines() -> DeadlineConfig {
    DeadlineConfig {
        floor_seconds: 1.0,
        ceiling_seconds: 2.0,
        reconnect_seconds: 60.0,
        ..DeadlineConfig::default()
    }
}

/// A real env_server and a fault proxy in front of it.
#[derive(Debug)]
pub struct FaultBed {
    /// The server (killed on drop).
    pub server: LocalServer,
    /// The proxy the agent goes through.
    pub proxy: FaultProxy,
}

impl FaultBed {
    /// Start a server allowing [`MAX_SESSIONS`] sessions, and a proxy to it with no
    /// fault.
    pub async fn start() -> FaultBed {
        Self::start_with(&[]).await
    }

    /// [`Self::start`] with more server flags.
    pub async fn start_with(extra: &[&str]) -> FaultBed {
        let mut args = vec!["--max-sessions".to_string(), MAX_SESSIONS.to_string()];
        args.extend(extra.iter().map(|s| s.to_string()));
        let server = crate::start_server(&args).await;
        let proxy = FaultProxy::start(server.address()).await;
        FaultBed { server, proxy }
    }

    /// `cfg` training through the proxy with [`test_deadlines`].
    pub fn through_proxy(&self, mut cfg: TrainConfig) -> TrainConfig {
        cfg.env.servers = vec![self.proxy.address()];
        cfg.env.deadlines = test_deadlines();
        cfg.validate().expect("a valid faulted config");
        cfg
    }

    /// Fails unless the server has no session open within `within`: sessions a broken
    /// stream held close once the close reaches the server, which the proxy passes on
    /// when no fault holds (the default lease, 120 s, is far longer).
    pub async fn assert_no_session_left(&self, within: Duration) {
        let started = Instant::now();
        while free_sessions(self.server.address(), MAX_SESSIONS).await < MAX_SESSIONS {
            assert!(
                started.elapsed() < within,
                "sessions still open on the server {within:?} after the run"
            );
            tokio::time::sleep(Duration::from_millis(200)).await;
        }
    }
}

/// How many sessions a new client can make on the server at `address` now, up to
/// `max` (the server's `--max-sessions`: `max` minus the sessions open); they are
/// closed again.
pub async fn free_sessions(address: &str, max: usize) -> usize {
    let client = EnvClient::connect(address).await.unwrap();
    let mut made = Vec::new();
    while made.len() < max {
        match client.make(&MakeOptions::new("dst", 1)).await {
            Ok(env) => made.push(env),
            Err(e) if e.status_kind() == Some(StatusKind::ResourceExhausted) => break,
            Err(e) => panic!("a Make to count the free sessions failed: {e}"),
        }
    }
    let free = made.len();
    for env in made {
        env.close().await.unwrap();
    }
    free
}

/// One fault of a plan, and how long it holds.
#[derive(Debug, Clone, Copy)]
pub struct Injection {
    /// What the proxy does.
    pub fault: Fault,
    /// For how long.
    pub hold: Duration,
}

/// An injected fault, and how long the run took to recover from it.
#[derive(Debug, Clone, Copy)]
pub struct Injected {
    /// The fault.
    pub fault: Fault,
    /// Seconds from its clearing to [`PROGRESS_CHUNKS`] answers after it.
    pub recovered_s: f64,
}

/// Chunks of answers (server to agent) that count as progress after a fault clears:
/// a dozen steps or more, so that a stray frame (a ping's answer) does not.
const PROGRESS_CHUNKS: usize = 30;

/// Runs `run` while `plan`'s faults are injected one after another through `proxy`,
/// each once the agent has made progress ([`PROGRESS_CHUNKS`] answers) since the last
/// cleared. Fails if the run ends before the plan does (its budget was too small to
/// test every fault) or if progress does not resume within `recover_within` of a
/// clearing.
pub async fn run_with_faults<T>(
    proxy: &FaultProxy,
    run: impl Future<Output = T>,
    plan: &[Injection],
    recover_within: Duration,
) -> (T, Vec<Injected>) {
    let mut run = pin!(run);
    let mut injected = Vec::new();
    let started = Instant::now();
    for (i, step) in plan.iter().enumerate() {
        let wait = async {
            if i == 0 {
                wait_for_chunks(proxy, Direction::Down, (started, PROGRESS_CHUNKS), None).await;
            }
            proxy.set(step.fault);
            tokio::time::sleep(step.hold).await;
            proxy.clear();
            let cleared = Instant::now();
            let recovered = wait_for_chunks(
                proxy,
                Direction::Down,
                (cleared, PROGRESS_CHUNKS),
                Some(recover_within),
            )
            .await;
            Injected {
                fault: step.fault,
                recovered_s: (recovered - cleared).as_secs_f64(),
            }
        };
        tokio::select! {
            done = wait => injected.push(done),
            _ = &mut run => panic!("the run ended before fault {i} of the plan ({:?}) was over", step.fault),
        }
    }
    eprintln!(
        "the faults' plan was over after {:.1} s",
        started.elapsed().as_secs_f64()
    );
    (run.await, injected)
}

/// When the `n`-th chunk going `way` after `after` went through `proxy`; fails after
/// `within` when given (no progress).
pub async fn wait_for_chunks(
    proxy: &FaultProxy,
    way: Direction,
    (after, n): (Instant, usize),
    within: Option<Duration>,
) -> Instant {
    loop {
        let at: Vec<Instant> = proxy
            .traffic()
            .iter()
            .filter(|c| c.direction == way && c.at > after)
            .map(|c| c.at)
            .collect();
        if at.len() >= n {
            return at[n - 1];
        }
        if let Some(within) = within {
            assert!(
                after.elapsed() < within,
                "{} chunks {way:?} through the proxy in the {within:?} after a fault cleared",
                at.len()
            );
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
}

/// The run reached its budget with the learner steps its pace allows, and wrote every
/// log row once: `learner.jsonl` a row per `log_period` learner steps, `episodes.csv`
/// a row per episode counted, in env-step order, none twice.
pub fn assert_complete(cfg: &TrainConfig, summary: &TrainSummary) {
    let run = &cfg.run;
    assert_eq!(summary.env_steps, run.total_env_steps, "env steps");
    let allowed = if cfg.learner.algorithm.on_policy() {
        // One learner step per batch of unrolls inserted (the final checkpoint's replay).
        let (_, progress) = latest_checkpoint(&summary.run_dir).expect("a final checkpoint");
        let inserted = progress
            .replay
            .expect("on-policy runs keep their unrolls")
            .inserted;
        inserted / cfg.learner.vmpo.batch_size as u64
    } else {
        ((run.total_env_steps - run.min_replay_transitions as u64) as f64
            * run.learner_steps_per_env_step)
            .floor() as u64
    };
    assert_eq!(summary.learner_steps, allowed, "learner steps");
    let logged = learner_rows(&summary.run_dir);
    let every: Vec<u64> = (1..=summary.learner_steps / run.log_period)
        .map(|i| i * run.log_period)
        .collect();
    assert_eq!(logged, every, "learner.jsonl rows");
    let text = std::fs::read_to_string(summary.run_dir.join("episodes.csv")).unwrap();
    let rows: Vec<&str> = text.lines().skip(1).collect();
    assert_eq!(rows.len() as u64, summary.episodes, "episodes.csv rows");
    let mut unique = rows.clone();
    unique.sort_unstable();
    unique.dedup();
    assert_eq!(
        unique.len(),
        rows.len(),
        "an episodes.csv row written twice"
    );
    let steps: Vec<u64> = rows
        .iter()
        .map(|r| r.split(',').next().unwrap().parse().unwrap())
        .collect();
    assert!(
        steps.windows(2).all(|w| w[0] <= w[1]) && steps.last() <= Some(&run.total_env_steps),
        "episodes.csv out of env-step order"
    );
}

/// The `learner_step` of every `learner.jsonl` row.
fn learner_rows(run_dir: &Path) -> Vec<u64> {
    std::fs::read_to_string(run_dir.join("learner.jsonl"))
        .unwrap()
        .lines()
        .map(|l| {
            let v: serde_json::Value = serde_json::from_str(l).unwrap();
            v["learner_step"].as_u64().expect("a learner_step field")
        })
        .collect()
}
