//! The chaos soak's two parts: random faults injected through a [`FaultProxy`] every few
//! seconds ([`Chaos`]), and the figures of the runs that rode them out ([`SoakReport`]).

use std::collections::BTreeMap;
use std::convert::Infallible;
use std::fmt::Write as _;
use std::time::Duration;

use agent::env::pool::EnvFaults;
use agent::runtime::train::TrainSummary;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::faults::Injection;
use crate::proxy::{Fault, FaultProxy};

/// Random faults, drawn from a seeded stream, and how many of each kind were injected.
#[derive(Debug)]
pub struct Chaos {
    rng: ChaCha8Rng,
    /// Faults injected, by kind.
    pub injected: BTreeMap<&'static str, u64>,
    /// Seconds faults held, in all.
    pub held_seconds: f64,
}

impl Chaos {
    /// A stream of faults from `seed`.
    pub fn new(seed: u64) -> Chaos {
        Chaos {
            rng: ChaCha8Rng::seed_from_u64(seed),
            injected: BTreeMap::new(),
            held_seconds: 0.0,
        }
    }

    /// Forever: wait 3 to 7 s, then hold a random fault for 0.5 to 3 s. Dropping the
    /// future may leave a fault set (clear the proxy after); it was counted when set.
    pub async fn inject_forever(&mut self, proxy: &FaultProxy) -> Infallible {
        loop {
            let gap = self.rng.random_range(3.0..7.0);
            tokio::time::sleep(Duration::from_secs_f64(gap)).await;
            let injection = self.draw();
            *self.injected.entry(kind(injection.fault)).or_default() += 1;
            self.held_seconds += injection.hold.as_secs_f64();
            proxy.set(injection.fault);
            tokio::time::sleep(injection.hold).await;
            proxy.clear();
        }
    }

    fn draw(&mut self) -> Injection {
        let ms = |v: u64| Duration::from_millis(v);
        let fault = match self.rng.random_range(0..7) {
            0 => Fault::Delay(ms(self.rng.random_range(20..300))),
            1 => Fault::Throttle(self.rng.random_range(5_000..50_000)),
            2 => Fault::Trickle(ms(1)),
            3 => Fault::Drop,
            4 => Fault::Reset,
            5 => Fault::Blackhole,
            _ => Fault::SlowClose(ms(self.rng.random_range(200..2_000))),
        };
        let hold = ms(self.rng.random_range(500..3_000));
        Injection { fault, hold }
    }
}

/// A fault's kind, for the report.
pub fn kind(fault: Fault) -> &'static str {
    match fault {
        Fault::None => "none",
        Fault::Delay(_) => "delay",
        Fault::Drop => "drop",
        Fault::Reset => "reset",
        Fault::Blackhole => "blackhole",
        Fault::Throttle(_) => "throttle",
        Fault::SlowClose(_) => "slow close",
        Fault::Trickle(_) => "trickle",
    }
}

/// What the soak's runs did, summed.
#[derive(Debug, Default)]
pub struct SoakReport {
    rounds: u64,
    runs: u64,
    env_steps: u64,
    learner_steps: u64,
    episodes: u64,
    faults: EnvFaults,
    round_seconds: Vec<f64>,
}

impl SoakReport {
    /// One round's runs (a population's members share their actors, so their
    /// `env_faults` are counted once).
    pub fn add_round(&mut self, summaries: &[TrainSummary], took: Duration) {
        self.rounds += 1;
        self.round_seconds.push(took.as_secs_f64());
        for s in summaries {
            self.runs += 1;
            self.env_steps += s.env_steps;
            self.learner_steps += s.learner_steps;
            self.episodes += s.episodes;
        }
        let f = &summaries[0].env_faults;
        self.faults.deadline_misses += f.deadline_misses;
        self.faults.restarts += f.restarts;
        self.faults.moves += f.moves;
        self.faults.seconds_lost += f.seconds_lost;
    }

    /// The figures, as Markdown.
    pub fn render(&self, chaos: &Chaos, elapsed: Duration) -> String {
        let mut out = String::new();
        let injected: u64 = chaos.injected.values().sum();
        let kinds: Vec<String> = chaos
            .injected
            .iter()
            .map(|(k, n)| format!("{k} {n}"))
            .collect();
        let longest = self.round_seconds.iter().copied().fold(0.0, f64::max);
        let lines = [
            ("soak wall time", format!("{:.0} s", elapsed.as_secs_f64())),
            (
                "faults injected",
                format!("{injected} ({})", kinds.join(", ")),
            ),
            (
                "seconds under a fault",
                format!("{:.0}", chaos.held_seconds),
            ),
            (
                "rounds / runs completed",
                format!("{} / {}", self.rounds, self.runs),
            ),
            ("longest round", format!("{longest:.0} s")),
            (
                "env steps / learner steps",
                format!("{} / {}", self.env_steps, self.learner_steps),
            ),
            ("episodes logged", self.episodes.to_string()),
            ("missed deadlines", self.faults.deadline_misses.to_string()),
            (
                "sessions made again (retries)",
                self.faults.restarts.to_string(),
            ),
            (
                "actor seconds lost to faults",
                format!("{:.1}", self.faults.seconds_lost),
            ),
            (
                "hangs, rows lost or duplicated, sessions left",
                "0 (checked after every round)".into(),
            ),
        ];
        let _ = writeln!(out, "| chaos soak | |\n|---|---|");
        for (what, value) in lines {
            let _ = writeln!(out, "| {what} | {value} |");
        }
        out
    }
}
