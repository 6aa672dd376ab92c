//! One full MO-MPO learner step at the humanoid-run size (Table 3):
//! obs 67, act 21, B = 512 snippets of T = 8, M = 20 samples, policy (400, 400, 300),
//! critic (500, 500, 400), K = 2 objectives: `task` (learned critic) and
//! `action_norm` (closed form, no critic).
//!
//! The step computes: target policy on N = (T+1)B = 4608 states, M = 20 samples each;
//! target critic forward on all N*M = 92,160 (state, action) pairs (V for Retrace and
//! Q for the E-step); target critic on the T*B = 4096 taken pairs; Retrace targets;
//! online critic forward+backward on the 4096 pairs and Adam; E-step weights and
//! temperature duals; decoupled M-step on the 4608 states x 20 samples, backward,
//! Adam on the policy and on the duals. Timed: median of 20 steps after 3 warm-up steps.
//! `agent/benches/learner_step_torch.py` is the same step in plain PyTorch.
//!
//! Unless `--no-torch`, the two alternate in the same invocation (same threads): the
//! script runs as a child process, and each of `--rounds` rounds (default: one per
//! step) times `--steps / --rounds` Rust steps, then as many PyTorch steps. On a
//! shared VM the machine's speed drifts by tens of percent within a minute; a round's
//! two figures see nearly the same machine, so the bench reports the median of the
//! per-round ratios and their quartiles, next to each side's overall median.
//!
//! Run: `cargo bench -p agent --bench learner_step [-- --threads N --steps N --rounds N --no-torch]`
//! (prints its figures last).
#![allow(clippy::print_stdout, reason = "a benchmark reports on stdout")]

mod common;

use agent::core::learner_config::{LearnerConfig, NetworkConfig};
use std::io::{BufRead, BufReader, Write as _};
use std::process::{Child, ChildStdin, ChildStdout, Command, Stdio};

fn main() {
    let mut cfg = LearnerConfig {
        objectives: common::task_and_action_norm(0.05),
        network: NetworkConfig {
            policy_layers: vec![400, 400, 300],
            critic_layers: vec![500, 500, 400],
            tanh_on_action_mean: false,
            min_variance: 1e-8,
            tanh_on_critic_action: false,
            ..NetworkConfig::default()
        },
        ..LearnerConfig::default()
    };
    cfg.mpo.beta_mean = 5e-3;
    cfg.mpo.beta_cov = 1e-6;
    cfg.mpo.learning_rate = 2e-4;
    cfg.mpo.adam_eps = 1e-8;
    let size = common::StepSize {
        name: "learner_step",
        obs_dim: 67,
        act_dim: 21,
        cfg,
    };
    if std::env::args().any(|a| a == "--no-torch") {
        common::run(size);
        return;
    }
    compare_with_torch(common::prepare(size));
}

/// The PyTorch script as a child process that times a round per line on its stdin.
struct TorchRounds {
    child: Child,
    stdin: ChildStdin,
    stdout: BufReader<ChildStdout>,
}

impl TorchRounds {
    fn start(threads: &str, rounds: usize, per_round: usize) -> Self {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        let script = root.join("agent/benches/learner_step_torch.py");
        let mut child = Command::new(root.join(".venv/bin/python"))
            .arg(script)
            .args(["--threads", threads])
            .args(["--rounds", &rounds.to_string()])
            .args(["--steps", &per_round.to_string()])
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .expect(
                "run .venv/bin/python agent/benches/learner_step_torch.py (made by scripts/setup.sh)",
            );
        let stdin = child.stdin.take().expect("piped");
        let stdout = BufReader::new(child.stdout.take().expect("piped"));
        let mut rounds = Self {
            child,
            stdin,
            stdout,
        };
        rounds.read_until("ready");
        rounds
    }

    /// Prints the script's lines up to the one starting with `prefix`; returns its rest.
    fn read_until(&mut self, prefix: &str) -> String {
        loop {
            let mut line = String::new();
            let n = self
                .stdout
                .read_line(&mut line)
                .expect("read the script's output");
            assert!(n > 0, "the PyTorch script ended before printing '{prefix}'");
            if let Some(rest) = line.trim_end().strip_prefix(prefix) {
                return rest.to_string();
            }
            print!("{line}");
        }
    }

    /// Times one round in the script and returns its median step in ms.
    fn round(&mut self) -> f64 {
        // ChildStdin is unbuffered: the line reaches the script at once.
        writeln!(self.stdin, "go").expect("write to the script");
        let v = self.read_until("round_ms_median=");
        v.parse()
            .unwrap_or_else(|_| panic!("a median in ms, got '{v}'"))
    }

    /// Waits for the script and returns its overall median step in ms.
    fn finish(mut self) -> f64 {
        let v = self.read_until("learner_step_ms_median=");
        let status = self.child.wait().expect("wait for the script");
        assert!(status.success(), "the PyTorch script failed: {status}");
        v.parse()
            .unwrap_or_else(|_| panic!("a median in ms, got '{v}'"))
    }
}

/// Alternates rounds of Rust and PyTorch steps and prints both medians and the ratio.
fn compare_with_torch(prepared: common::Prepared) {
    let common::Prepared {
        mut learner,
        batch,
        steps,
    } = prepared;
    let rounds: usize = common::arg("--rounds", steps).max(1);
    let per_round = steps.div_ceil(rounds).max(1);
    let threads = tch::get_num_threads().to_string();
    common::warm_up(&mut learner, &batch, 3);
    let mut torch = TorchRounds::start(&threads, rounds, per_round);
    let (mut rust_all, mut phases, mut ratios) = (Vec::new(), [0.0; 4], Vec::new());
    for r in 1..=rounds {
        let t = common::timed(&mut learner, &batch, per_round);
        let rust_ms = common::median(t.totals.clone());
        let torch_ms = torch.round();
        let ratio = rust_ms / torch_ms;
        println!(
            "  round {r}/{rounds}: Rust {rust_ms:.1} ms, PyTorch {torch_ms:.1} ms, ratio {ratio:.3}"
        );
        ratios.push(ratio);
        rust_all.extend(t.totals);
        phases.iter_mut().zip(t.phases).for_each(|(a, v)| *a += v);
    }
    let torch_ms = torch.finish();
    println!("Rust phases:");
    common::print_phases(&phases, common::MPO_PHASES);
    let rust_ms = common::median(rust_all);
    ratios.sort_by(f64::total_cmp);
    // Nearest ranks, rounded outwards so that two rounds report both.
    let last = ratios.len() - 1;
    let (lo, hi) = (ratios[last / 4], ratios[(3 * last).div_ceil(4)]);
    println!("learner_step_ms_median={rust_ms:.2}");
    println!("torch_learner_step_ms_median={torch_ms:.1}");
    println!(
        "ratio_rust_over_torch={:.3}  (median of {rounds} interleaved rounds of {per_round} step(s), quartiles {lo:.3}-{hi:.3}; overall medians Rust {rust_ms:.1} ms, PyTorch {torch_ms:.1} ms; {threads} threads)",
        common::median(ratios)
    );
}
