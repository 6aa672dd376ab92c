//! The network part of a learner step for P members: stacked (one batched program,
//! `nets` member axis) against P separate single networks, at Deep Sea Treasure's
//! sizes (issue 22's go/no-go measurement, research/population.md step 1).
//!
//! Per member, as the categorical MO-MPO step does it: obs 2, A = 4 actions,
//! B = 128 snippets of T = 1 (N = 256 states, 128 taken pairs), policy (64, 64) and
//! critic (128, 128) with C = 2 heads on a shared first layer:
//! - target critic, untracked, on all A actions of the N states;
//! - target policy, untracked, on the N states;
//! - online critic forward + backward on the 128 taken pairs (squared error);
//! - online policy forward + backward on the N states (weighted log-likelihood);
//! - one Adam step on each network (the learner's own `algo::adam::Adam`).
//!
//! The critic here reads `[obs, one_hot(a)]` through one first layer (the learner's
//! critic splits that layer to share the observation half); the E-step, Retrace
//! and duals are not included: this measures what batching the networks saves.
//!
//! Each round times `--steps` stacked steps, then as many of the P singles in turn,
//! on one thread; the ratio is the median over rounds of the per-round ratios (the
//! machine's speed drifts within a minute, a round's two figures see the same one).
//!
//! Run: `cargo bench -p agent --bench population_step [-- --sizes 1,2,6,16,39 --steps 10 --rounds 7 --scale 1]`
//! (`--scale 64`: 4 states and 2 pairs per member, the fixed cost alone).
#![allow(clippy::print_stdout, reason = "a benchmark reports on stdout")]

use agent::algo::adam::{Adam, AdamConfig};
use agent::nets::Members;
use agent::nets::heads::HeadStack;
use agent::nets::mlp::{Dense, LayerNormMlp};
use std::time::Instant;
use tch::{Device, Kind, Tensor, nn};

const OBS: i64 = 2;
const ACTIONS: i64 = 4;
/// DST's N = (T + 1) B states and T B taken pairs; `--scale` divides both, so that a
/// tiny batch shows the step's fixed cost (dispatch, autograd, Adam) alone.
const STATES: i64 = 256;
const PAIRS: i64 = 128;
const HEADS: i64 = 2;

/// Online and target copies of one network of `members` members, with its Adam.
struct Networks {
    _vs: nn::VarStore,
    _target_vs: nn::VarStore,
    critic: (LayerNormMlp, HeadStack),
    target_critic: (LayerNormMlp, HeadStack),
    policy: (LayerNormMlp, Dense),
    target_policy: (LayerNormMlp, Dense),
    adam: Adam,
}

fn build_critic(p: &nn::Path, m: Members) -> (LayerNormMlp, HeadStack) {
    (
        LayerNormMlp::with_members(&(p / "critic"), OBS + ACTIONS, &[128], m),
        HeadStack::with_members(&(p / "heads"), HEADS, &[128, 128], m),
    )
}

fn build_policy(p: &nn::Path, m: Members) -> (LayerNormMlp, Dense) {
    (
        LayerNormMlp::with_members(&(p / "policy"), OBS, &[64, 64], m),
        Dense::with_members(&(p / "logits"), 64, ACTIONS, 64, true, m),
    )
}

impl Networks {
    fn new(members: Members) -> Self {
        let vs = nn::VarStore::new(Device::Cpu);
        let mut target_vs = nn::VarStore::new(Device::Cpu);
        let (critic, policy) = (
            build_critic(&vs.root(), members),
            build_policy(&vs.root(), members),
        );
        let target_critic = build_critic(&target_vs.root(), members);
        let target_policy = build_policy(&target_vs.root(), members);
        target_vs.copy(&vs).expect("same layout");
        target_vs.freeze();
        let adam = Adam::for_var_store(&vs, AdamConfig::new(3e-4, 1e-3));
        Self {
            _vs: vs,
            _target_vs: target_vs,
            critic,
            target_critic,
            policy,
            target_policy,
            adam,
        }
    }

    /// One step on member-first inputs: `obs [P, N, O]`, `pairs [P, R, O + A]`,
    /// `all [P, A N, O + A]`, `targets [P, R, C]`, `weights [P, N, A]`.
    fn step(&mut self, input: &Inputs) {
        tch::no_grad(|| {
            let (torso, heads) = &self.target_critic;
            let _q_all = heads.forward_members(&torso.forward_members(&input.all));
            let (torso, logits) = &self.target_policy;
            let _prior = logits.forward_members(&torso.forward_members(&input.obs));
        });
        let (torso, heads) = &self.critic;
        let q = heads.forward_members(&torso.forward_members(&input.pairs));
        let critic_loss = (q - &input.targets).square().mean(Kind::Float);
        let (torso, logits) = &self.policy;
        let log_pi = logits
            .forward_members(&torso.forward_members(&input.obs))
            .log_softmax(-1, Kind::Float);
        let policy_loss = -(log_pi * &input.weights).sum(Kind::Float) / input.states as f64;
        self.adam.zero_grad();
        (critic_loss + policy_loss).backward();
        self.adam.step();
    }
}

struct Inputs {
    states: i64,
    obs: Tensor,
    pairs: Tensor,
    all: Tensor,
    targets: Tensor,
    weights: Tensor,
}

impl Inputs {
    fn new(p: i64, scale: i64) -> Self {
        let opts = (Kind::Float, Device::Cpu);
        let (states, pairs) = (STATES / scale, PAIRS / scale);
        Self {
            states,
            obs: Tensor::randn([p, states, OBS], opts),
            pairs: Tensor::randn([p, pairs, OBS + ACTIONS], opts),
            all: Tensor::randn([p, ACTIONS * states, OBS + ACTIONS], opts),
            targets: Tensor::randn([p, pairs, HEADS], opts),
            weights: Tensor::rand([p, states, ACTIONS], opts),
        }
    }

    /// Member `i`'s slice, still member-first (`[1, ..]`).
    fn member(&self, i: i64) -> Self {
        let slice = |t: &Tensor| t.narrow(0, i, 1).contiguous();
        Self {
            states: self.states,
            obs: slice(&self.obs),
            pairs: slice(&self.pairs),
            all: slice(&self.all),
            targets: slice(&self.targets),
            weights: slice(&self.weights),
        }
    }
}

/// Multiply-adds of one member's step at `states` states and `pairs` pairs, forward
/// passes once, the two trained passes three times (forward, and backward's two
/// products per layer): critic first layer (O + A) x 128 and per head 128 x 128 +
/// 128 x 1; policy O x 64 + 64 x 64 + 64 x A. At DST's 256 / 128 that is
/// 34.6M (target critic on 1024 rows) + 1.15M (target policy) + 3 x 4.3M (critic)
/// + 3 x 1.15M (policy) = 52M multiply-adds, 104 MFLOP.
fn flops_per_member(states: i64, pairs: i64) -> f64 {
    let critic_row = (OBS + ACTIONS) * 128 + HEADS * (128 * 128 + 128);
    let policy_row = OBS * 64 + 64 * 64 + 64 * ACTIONS;
    let macs = ACTIONS * states * critic_row
        + states * policy_row
        + 3 * pairs * critic_row
        + 3 * states * policy_row;
    2.0 * macs as f64
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn arg(name: &str) -> Option<String> {
    let args: Vec<String> = std::env::args().collect();
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1).cloned())
}

fn main() {
    tch::set_num_threads(1);
    tch::manual_seed(0);
    let sizes: Vec<i64> = arg("--sizes")
        .unwrap_or_else(|| "1,2,6,16,39".into())
        .split(',')
        .map(|s| s.parse().expect("--sizes: comma-separated member counts"))
        .collect();
    let steps: usize = arg("--steps").map_or(10, |s| s.parse().expect("--steps: a count"));
    let rounds: usize = arg("--rounds").map_or(7, |s| s.parse().expect("--rounds: a count"));
    let scale: i64 = arg("--scale").map_or(1, |s| s.parse().expect("--scale: a divisor of 128"));
    println!(
        "population_step: DST-size networks, {} states per member, one thread, {rounds} rounds of {steps} steps",
        STATES / scale
    );
    let flops = flops_per_member(STATES / scale, PAIRS / scale);
    println!("{:.1} MFLOP per member step (GEMMs only)", flops / 1e6);
    println!(
        "{:>4} {:>12} {:>12} {:>14} {:>12} {:>10} {:>10}",
        "P", "stacked ms", "t(P)/t(1)", "per member ms", "P singles ms", "speedup", "GFLOP/s"
    );
    let mut t1 = None;
    for &p in &sizes {
        let members = Members::new(p).expect("member counts are >= 1");
        let mut stacked = Networks::new(members);
        let mut singles: Vec<Networks> = (0..p).map(|_| Networks::new(Members::ONE)).collect();
        let input = Inputs::new(p, scale);
        let parts: Vec<Inputs> = (0..p).map(|i| input.member(i)).collect();
        stacked.step(&input);
        for (net, part) in singles.iter_mut().zip(&parts) {
            net.step(part);
        }
        let (mut stacked_ms, mut singles_ms, mut ratios) = (Vec::new(), Vec::new(), Vec::new());
        for _ in 0..rounds {
            let start = Instant::now();
            for _ in 0..steps {
                stacked.step(&input);
            }
            let a = start.elapsed().as_secs_f64() * 1e3 / steps as f64;
            let start = Instant::now();
            for _ in 0..steps {
                for (net, part) in singles.iter_mut().zip(&parts) {
                    net.step(part);
                }
            }
            let b = start.elapsed().as_secs_f64() * 1e3 / steps as f64;
            stacked_ms.push(a);
            singles_ms.push(b);
            ratios.push(b / a);
        }
        let (a, b) = (median(stacked_ms), median(singles_ms));
        let base = *t1.get_or_insert(a);
        println!(
            "{p:>4} {a:>12.2} {:>12.2} {:>14.3} {b:>12.2} {:>9.2}x {:>10.1}",
            a / base,
            a / p as f64,
            median(ratios),
            flops * p as f64 / (a * 1e6)
        );
    }
}
