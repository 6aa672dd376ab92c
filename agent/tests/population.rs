//! Population learners (issue 22): P members trained as one batched program compute
//! what P single learners compute. Each case builds a population of three from
//! three configs that differ in seed and ε (or scalarization weights), and the three
//! single learners of the same configs; member p and single p start from the same
//! parameters (bit for bit), get the same batch and the same sampling noise at every
//! step, and after 50 learner steps agree in parameters, duals and every logged
//! statistic within 1e-5 relative. Batched and single GEMMs may round differently,
//! so agreement is to float32 rounding, not bitwise.
//!
//! Independence: a member's results do not change when the other members are
//! reordered, or when another member's rewards are NaN.

mod common;

use agent::core::algo::{Learner, LearnerDims, LearnerStats, NoiseSource, SnippetBatch};
use agent::core::learner_config::{
    Algorithm, KlConstraint, LearnerConfig, ObjectiveConfig, ObjectiveSource, ObjectiveWeight,
};
use agent::core::nets::{ActionKind, NamedArray};
use agent::core::random::{Purpose, StreamKey};
use common::small_config;
use tch::{Device, Kind, Tensor};

const STEPS: u64 = 50;

/// A member's batch at step `step`: random observations, actions and rewards from a
/// stream keyed by the member's seed; behaviour log-probs off the policy's; one
/// terminal in snippet 0 and, when `padded`, an episode end after which snippet
/// `1 + seed % 3` is padding (so members have different numbers of real states).
fn batch(dims: &LearnerDims, t: i64, b: i64, seed: u64, step: u64, padded: bool) -> SnippetBatch {
    let mut s = StreamKey::new(seed, Purpose::Replay, 77).at(step);
    let cpu = Device::Cpu;
    let observations = s.normal(&[t + 1, b, dims.obs_dim], cpu);
    let actions = match dims.action {
        ActionKind::Continuous { dim } => s.normal(&[t, b, dim], cpu),
        ActionKind::Discrete { n } => (s.uniform(&[t, b], cpu) * n as f64)
            .floor()
            .to_kind(Kind::Int64)
            .clamp_max(n - 1),
    };
    let k = dims.reward_names.len() as i64;
    let rewards = s.normal(&[t, b, k], cpu);
    let behaviour_log_probs = s.uniform(&[t, b], cpu) * -2.0 - 0.5;
    let discounts = Tensor::ones([t, b], (Kind::Float, cpu));
    let valid = Tensor::ones([t, b], (Kind::Float, cpu));
    let _ = discounts.get(0).narrow(0, 0, 1).fill_(0.0);
    if padded {
        // Snippet j's episode ends (terminal) at step 0; its later steps are padding.
        let j = 1 + (seed % 3) as i64;
        let _ = discounts.get(0).narrow(0, j, 1).fill_(0.0);
        if t > 1 {
            let _ = valid.narrow(0, 1, t - 1).narrow(1, j, 1).fill_(0.0);
        } else {
            // T = 1: the whole snippet is padding.
            let _ = valid.narrow(1, j, 1).fill_(0.0);
        }
    }
    SnippetBatch {
        observations,
        actions,
        rewards,
        discounts,
        behaviour_log_probs,
        valid,
    }
}

/// Given noise for `steps` steps of one member (Gaussian policies), keyed by seed.
fn noise(learner: &Learner, seed: u64, steps: u64) -> NoiseSource {
    let s = learner.settings();
    let n = (s.sequence_length as i64 + 1) * s.batch_size as i64;
    let ActionKind::Continuous { dim } = learner.dims().action else {
        return NoiseSource::Given(Default::default());
    };
    let m = learner.config().mpo.num_samples;
    NoiseSource::Given(
        (0..steps)
            .map(|i| {
                StreamKey::new(seed, Purpose::LearnerNoise, 99)
                    .at(i)
                    .normal(&[m, n, dim], Device::Cpu)
            })
            .collect(),
    )
}

/// |a - b| <= 1e-5 |b| + 1e-6, elementwise.
#[track_caller]
fn close(a: &[f32], b: &[f32], what: &str) {
    assert_eq!(a.len(), b.len(), "{what}: lengths");
    for (i, (x, y)) in a.iter().zip(b).enumerate() {
        let tol = 1e-5 * y.abs() + 1e-6;
        assert!((x - y).abs() <= tol, "{what}[{i}]: {x} vs {y}");
    }
}

#[track_caller]
fn close_params(a: &[NamedArray], b: &[NamedArray], what: &str) {
    assert_eq!(a.len(), b.len());
    for (x, y) in a.iter().zip(b) {
        assert_eq!((&x.name, &x.shape), (&y.name, &y.shape), "{what}");
        close(&x.data, &y.data, &format!("{what} {}", x.name));
    }
}

#[track_caller]
fn close_stats(a: &LearnerStats, b: &LearnerStats, what: &str) {
    assert_eq!(a.step, b.step);
    close(
        &a.critic_loss,
        &b.critic_loss,
        &format!("{what} critic loss"),
    );
    close(
        &a.temperature,
        &b.temperature,
        &format!("{what} temperature"),
    );
    close(&a.estep_kl, &b.estep_kl, &format!("{what} E-step KL"));
    close(&a.q_mean, &b.q_mean, &format!("{what} Q mean"));
    close(&a.alpha, &b.alpha, &format!("{what} alpha"));
    close(&a.policy_kl, &b.policy_kl, &format!("{what} policy KL"));
}

/// Trains `cfgs` as one population and as single learners, step by step, and checks
/// that they agree; `padded` adds episode ends and padding to the batches.
fn members_match_singles(cfgs: Vec<LearnerConfig>, dims: LearnerDims, padded: bool) {
    let _rng = common::exclusive_rng();
    let seeds: Vec<u64> = cfgs.iter().map(|c| c.seed).collect();
    let mut population = Learner::population(cfgs.clone(), dims.clone(), Device::Cpu).unwrap();
    let mut singles: Vec<Learner> = cfgs
        .into_iter()
        .map(|c| Learner::new(c, dims.clone(), Device::Cpu).unwrap())
        .collect();
    for (p, single) in singles.iter().enumerate() {
        assert_eq!(
            population.member_parameters(p),
            single.member_parameters(0),
            "member {p} starts as its single learner, bit for bit"
        );
    }
    population.set_member_noise_sources(
        seeds
            .iter()
            .map(|&s| noise(&population, s, STEPS))
            .collect(),
    );
    for (single, &s) in singles.iter_mut().zip(&seeds) {
        let source = noise(single, s, STEPS);
        single.set_noise_source(source);
    }
    let settings = *population.settings();
    let (t, b) = (settings.sequence_length as i64, settings.batch_size as i64);
    for step in 0..STEPS {
        let batches: Vec<SnippetBatch> = seeds
            .iter()
            .map(|&s| batch(&dims, t, b, s, step, padded))
            .collect();
        let stats = population.step_members(&batches).unwrap();
        for (p, (single, batch)) in singles.iter_mut().zip(&batches).enumerate() {
            let want = single.step(batch).unwrap();
            close_stats(&stats[p], &want, &format!("step {step}, member {p}"));
        }
    }
    for (p, single) in singles.iter().enumerate() {
        close_params(
            &population.member_parameters(p),
            &single.member_parameters(0),
            &format!("member {p}"),
        );
        let (eta, alpha) = population.member_duals(p);
        let (want_eta, want_alpha) = single.member_duals(0);
        close(&eta, &want_eta, &format!("member {p} eta"));
        close(&alpha, &want_alpha, &format!("member {p} alpha"));
    }
}

fn continuous_dims() -> LearnerDims {
    LearnerDims {
        action_bounds: None,
        obs_dim: common::OBS,
        action: ActionKind::Continuous { dim: 2 },
        reward_names: vec!["task".into(), "action_norm".into()],
        obs_leaves: Vec::new(),
    }
}

fn discrete_dims() -> LearnerDims {
    LearnerDims {
        action_bounds: None,
        obs_dim: common::OBS,
        action: ActionKind::Discrete { n: 4 },
        reward_names: vec!["treasure".into(), "time".into()],
        obs_leaves: Vec::new(),
    }
}

/// Continuous MO-MPO members (task learned, action norm in closed form) with seeds
/// 5, 6, 7 and ε_action_norm 0.01, 0 (no influence) and 0.05.
fn continuous_members(change: impl Fn(&mut LearnerConfig)) -> Vec<LearnerConfig> {
    [(5, 0.01), (6, 0.0), (7, 0.05)]
        .into_iter()
        .map(|(seed, eps)| {
            let mut cfg = small_config();
            cfg.seed = seed;
            cfg.objectives = common::task_and_action_norm(eps);
            change(&mut cfg);
            cfg
        })
        .collect()
}

/// Learned `treasure` (ε given) and `time` (ε 0.02) objectives.
fn treasure_and_time(eps: f64) -> Vec<ObjectiveConfig> {
    ["treasure", "time"]
        .into_iter()
        .zip([eps, 0.02])
        .map(|(name, epsilon)| ObjectiveConfig {
            name: name.into(),
            epsilon,
            source: ObjectiveSource::Learned,
        })
        .collect()
}

/// Scalarization weights w (treasure) and 1 - w (time).
fn treasure_time_weights(w: f64) -> Vec<ObjectiveWeight> {
    [("treasure", w), ("time", 1.0 - w)]
        .into_iter()
        .map(|(name, weight)| ObjectiveWeight {
            name: name.into(),
            weight,
        })
        .collect()
}

/// Discrete MO-MPO members on Deep Sea Treasure's settings (T = 1, exact E-step).
fn discrete_members() -> Vec<LearnerConfig> {
    [(5, 0.1), (6, 0.3), (7, 0.01)]
        .into_iter()
        .map(|(seed, eps)| {
            let mut cfg = small_config();
            cfg.seed = seed;
            cfg.mpo.retrace_length = 1;
            cfg.mpo.discount = 0.999;
            cfg.mpo.beta_categorical = 0.001;
            cfg.objectives = treasure_and_time(eps);
            cfg
        })
        .collect()
}

#[test]
fn gaussian_mompo_members_are_their_single_learners() {
    members_match_singles(continuous_members(|_| {}), continuous_dims(), true);
}

#[test]
fn per_dimension_kl_members_are_their_single_learners() {
    members_match_singles(
        continuous_members(|c| c.mpo.kl_constraint = KlConstraint::PerDimension),
        continuous_dims(),
        false,
    );
}

#[test]
fn categorical_mompo_members_with_padding_are_their_single_learners() {
    members_match_singles(discrete_members(), discrete_dims(), true);
}

#[test]
fn scalarized_mpo_members_are_their_single_learners() {
    let cfgs = [(5, 0.9), (6, 0.5), (7, 0.1)]
        .into_iter()
        .map(|(seed, w)| {
            let mut cfg = small_config();
            cfg.seed = seed;
            cfg.algorithm = Algorithm::ScalarizedMpo {
                epsilon: 0.1,
                weights: treasure_time_weights(w),
            };
            cfg
        })
        .collect();
    members_match_singles(cfgs, discrete_dims(), true);
}

/// MO-V-MPO members (two learned objectives) on unrolls of 4 with two epochs of two
/// minibatches, so that each member shuffles its own unrolls; seeds 5, 6, 7 and
/// per-member ε.
fn vmpo_members(algorithm: impl Fn(f64) -> Algorithm) -> Vec<LearnerConfig> {
    [(5, 0.1), (6, 0.5), (7, 0.01)]
        .into_iter()
        .map(|(seed, eps)| {
            let mut cfg = small_config();
            cfg.seed = seed;
            cfg.algorithm = algorithm(eps);
            cfg.vmpo.unroll_length = 4;
            cfg.vmpo.batch_size = 8;
            cfg.vmpo.learning_rate = 1e-3;
            cfg.vmpo.target_update_period = 4;
            cfg.vmpo.epochs = 2;
            cfg.vmpo.minibatches = 2;
            cfg.objectives = treasure_and_time(eps);
            cfg
        })
        .collect()
}

fn gaussian_vmpo_dims() -> LearnerDims {
    LearnerDims {
        reward_names: vec!["treasure".into(), "time".into()],
        ..continuous_dims()
    }
}

#[test]
fn gaussian_mo_vmpo_members_with_padding_are_their_single_learners() {
    members_match_singles(
        vmpo_members(|_| Algorithm::MoVmpo),
        gaussian_vmpo_dims(),
        true,
    );
}

#[test]
fn categorical_mo_vmpo_members_with_padding_are_their_single_learners() {
    members_match_singles(vmpo_members(|_| Algorithm::MoVmpo), discrete_dims(), true);
}

#[test]
fn scalarized_vmpo_members_are_their_single_learners() {
    let cfgs = vmpo_members(|w| Algorithm::ScalarizedVmpo {
        epsilon: 0.1,
        weights: treasure_time_weights(w),
    });
    members_match_singles(cfgs, discrete_dims(), true);
}

/// Member parameters after `steps` steps of a population of `cfgs`, with member
/// `nan`'s rewards replaced by NaN when given.
fn train(cfgs: &[LearnerConfig], dims: &LearnerDims, nan: Option<usize>) -> Vec<Vec<NamedArray>> {
    let mut population = Learner::population(cfgs.to_vec(), dims.clone(), Device::Cpu).unwrap();
    let settings = *population.settings();
    let (t, b) = (settings.sequence_length as i64, settings.batch_size as i64);
    for step in 0..20 {
        let batches: Vec<SnippetBatch> = cfgs
            .iter()
            .enumerate()
            .map(|(p, c)| {
                let mut batch = batch(dims, t, b, c.seed, step, true);
                if nan == Some(p) {
                    batch.rewards = batch.rewards.full_like(f64::NAN);
                }
                batch
            })
            .collect();
        population.step_members(&batches).unwrap();
    }
    (0..cfgs.len())
        .map(|p| population.member_parameters(p))
        .collect()
}

#[test]
fn a_member_does_not_see_the_order_or_the_nans_of_the_others() {
    let _rng = common::exclusive_rng();
    independent_members(continuous_members(|_| {}), continuous_dims());
    independent_members(vmpo_members(|_| Algorithm::MoVmpo), discrete_dims());
}

/// Reordering `cfgs`, or giving member 1 NaN rewards, leaves the others' parameters
/// as they were.
fn independent_members(cfgs: Vec<LearnerConfig>, dims: LearnerDims) {
    let dims = &dims;
    let base = train(&cfgs, dims, None);
    // Reversed order: member p of the base is member 2 - p here.
    let reversed: Vec<LearnerConfig> = cfgs.iter().rev().cloned().collect();
    let flipped = train(&reversed, dims, None);
    for p in 0..3 {
        close_params(&flipped[2 - p], &base[p], &format!("member {p} reordered"));
    }
    // Member 1's rewards are NaN: its parameters go NaN, the others' stay as they were.
    let poisoned = train(&cfgs, dims, Some(1));
    assert!(
        poisoned[1]
            .iter()
            .any(|a| a.data.iter().any(|v| v.is_nan())),
        "the NaN member learns from its NaN rewards"
    );
    for p in [0, 2] {
        close_params(
            &poisoned[p],
            &base[p],
            &format!("member {p} beside a NaN member"),
        );
        assert!(
            poisoned[p]
                .iter()
                .all(|a| a.data.iter().all(|v| v.is_finite()))
        );
    }
}

#[test]
fn members_that_cannot_batch_are_refused_by_name() {
    let mut cfgs = continuous_members(|_| {});
    cfgs[2].mpo.batch_size = 8;
    let err = Learner::population(cfgs, continuous_dims(), Device::Cpu).unwrap_err();
    let text = err.to_string();
    assert!(
        text.contains("population member 2") && text.contains("batch_size"),
        "{text}"
    );
    let err = Learner::population(Vec::new(), continuous_dims(), Device::Cpu).unwrap_err();
    assert!(err.to_string().contains("at least one member"), "{err}");
}
