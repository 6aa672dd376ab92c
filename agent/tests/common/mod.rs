//! Small learners and random snippet batches shared by the integration tests.
#![allow(dead_code, unreachable_pub, reason = "each test file uses a subset")]

use agent::core::algo::{Learner, LearnerDims, SnippetBatch};
use agent::core::learner_config::{
    Algorithm, Architecture, LearnerConfig, NetworkConfig, ObjectiveConfig, ObjectiveSource,
    ObjectiveWeight,
};
use agent::core::nets::{ActionKind, ObsLeaf};
use tch::{Device, Kind, Tensor};

pub const OBS: i64 = 3;

/// Holds a test binary's tests that draw from libtorch's process-global generator
/// (learner construction seeds it; sampling draws from it) to one at a time, with one
/// libtorch thread: interleaved draws from tests on other threads would change a
/// run's numbers, so comparisons of two runs could fail by chance. The networks are
/// tiny, so more threads would only add synchronisation cost.
pub fn exclusive_rng() -> std::sync::MutexGuard<'static, ()> {
    static RNG: std::sync::Mutex<()> = std::sync::Mutex::new(());
    let guard = RNG.lock().unwrap_or_else(|e| e.into_inner());
    tch::set_num_threads(1);
    guard
}

pub fn small_config() -> LearnerConfig {
    let mut cfg = LearnerConfig {
        network: NetworkConfig {
            policy_layers: vec![16, 16],
            critic_layers: vec![32, 16],
            ..NetworkConfig::default()
        },
        seed: 5,
        ..LearnerConfig::default()
    };
    cfg.mpo.num_samples = 6;
    cfg.mpo.retrace_length = 3;
    cfg.mpo.batch_size = 16;
    cfg.mpo.learning_rate = 1e-3;
    cfg.mpo.target_update_period = 4;
    cfg
}

/// Continuous MO-MPO: `task` learned, `action_norm` closed form.
pub fn continuous_learner() -> Learner {
    continuous_learner_with(|_| {})
}

/// `continuous_learner` with config changes.
pub fn continuous_learner_with(change: impl FnOnce(&mut LearnerConfig)) -> Learner {
    let mut cfg = small_config();
    change(&mut cfg);
    cfg.objectives = task_and_action_norm(0.01);
    let dims = LearnerDims {
        action_bounds: None,
        obs_dim: OBS,
        action: ActionKind::Continuous { dim: 2 },
        reward_names: vec!["task".into(), "action_norm".into()],
        obs_leaves: Vec::new(),
    };
    Learner::new(cfg, dims, Device::Cpu).unwrap()
}

/// `task` learned with ε 0.1, `action_norm` in closed form with `action_norm_epsilon`.
pub fn task_and_action_norm(action_norm_epsilon: f64) -> Vec<ObjectiveConfig> {
    vec![
        ObjectiveConfig {
            name: "task".into(),
            epsilon: 0.1,
            source: ObjectiveSource::Learned,
        },
        ObjectiveConfig {
            name: "action_norm".into(),
            epsilon: action_norm_epsilon,
            source: ObjectiveSource::ActionNorm,
        },
    ]
}

/// Discrete scalarized MPO with one-step TD (A.2 settings).
pub fn discrete_scalarized_learner(target_update_period: u64) -> Learner {
    let mut cfg = small_config();
    cfg.mpo.target_update_period = target_update_period;
    cfg.algorithm = Algorithm::ScalarizedMpo {
        epsilon: 0.1,
        weights: vec![
            ObjectiveWeight {
                name: "treasure".into(),
                weight: 0.7,
            },
            ObjectiveWeight {
                name: "time".into(),
                weight: 0.3,
            },
        ],
    };
    cfg.mpo.retrace_length = 1;
    cfg.mpo.discount = 0.999;
    let dims = LearnerDims {
        action_bounds: None,
        obs_dim: OBS,
        action: ActionKind::Discrete { n: 4 },
        reward_names: vec!["treasure".into(), "time".into()],
        obs_leaves: Vec::new(),
    };
    Learner::new(cfg, dims, Device::Cpu).unwrap()
}

/// A random batch matching `learner`, with a terminal in snippet 0.
pub fn random_batch(learner: &Learner, seed: i64) -> SnippetBatch {
    tch::manual_seed(seed);
    let settings = learner.settings();
    let (t, b) = (settings.sequence_length as i64, settings.batch_size as i64);
    let dims = learner.dims();
    let opts = (Kind::Float, Device::Cpu);
    let observations = Tensor::randn([t + 1, b, dims.obs_dim], opts);
    let obs_flat = observations.narrow(0, 0, t).reshape([t * b, dims.obs_dim]);
    let act = learner.act(&obs_flat, false);
    let actions = match dims.action {
        ActionKind::Continuous { dim } => act.actions.reshape([t, b, dim]),
        ActionKind::Discrete { .. } => act.actions.reshape([t, b]),
    };
    let k = dims.reward_names.len() as i64;
    let rewards = Tensor::randn([t, b, k], opts);
    let discounts = Tensor::ones([t, b], opts);
    let _ = discounts.get(0).narrow(0, 0, 1).fill_(0.0);
    // Behaviour log-probs slightly off the policy's so some c < 1.
    let behaviour_log_probs = act.log_probs.reshape([t, b]) + Tensor::randn([t, b], opts) * 0.3;
    SnippetBatch {
        observations,
        actions,
        rewards,
        discounts,
        behaviour_log_probs,
        valid: Tensor::ones([t, b], opts),
    }
}

/// MO-V-MPO with A.3's mocap torso (reference leaf, latent) and two learned objectives.
pub fn movmpo_mocap_learner() -> Learner {
    movmpo_mocap_learner_with(|_| {})
}

/// `movmpo_mocap_learner` with config changes (applied last).
pub fn movmpo_mocap_learner_with(change: impl FnOnce(&mut LearnerConfig)) -> Learner {
    let mut cfg = small_config();
    cfg.algorithm = Algorithm::MoVmpo;
    cfg.objectives = ["task", "effort"]
        .iter()
        .map(|name| ObjectiveConfig {
            name: (*name).into(),
            epsilon: 0.1,
            source: ObjectiveSource::Learned,
        })
        .collect();
    cfg.network.architecture = Architecture::Mocap {
        encoder_layers: vec![8],
        latent_dim: 3,
        reference_match: "reference".into(),
    };
    cfg.network.critic_shared_layers = 2;
    cfg.vmpo.unroll_length = 4;
    cfg.vmpo.batch_size = 5;
    cfg.vmpo.target_update_period = 2;
    change(&mut cfg);
    let dims = LearnerDims {
        action_bounds: None,
        obs_dim: OBS,
        action: ActionKind::Continuous { dim: 2 },
        reward_names: vec!["task".into(), "effort".into()],
        obs_leaves: vec![
            ObsLeaf {
                name: "walker/joints".into(),
                dim: 1,
            },
            ObsLeaf {
                name: "walker/reference_pos".into(),
                dim: 2,
            },
        ],
    };
    Learner::new(cfg, dims, Device::Cpu).unwrap()
}

/// The one-state bandit of the behavioural tests: a 1-D continuous action, no
/// observation to speak of (one zero), and two learned objectives "right" and "left"
/// with the given epsilons, on a small policy (one layer of 16, untanh'd mean) and a
/// critic of `critic_layers`. Each test sets its algorithm's own rates on the result.
pub fn bandit_config(
    algorithm: Algorithm,
    eps: [f64; 2],
    critic_layers: Vec<i64>,
    seed: u64,
) -> LearnerConfig {
    LearnerConfig {
        algorithm,
        objectives: ["right", "left"]
            .into_iter()
            .zip(eps)
            .map(|(name, epsilon)| ObjectiveConfig {
                name: name.into(),
                epsilon,
                source: ObjectiveSource::Learned,
            })
            .collect(),
        network: NetworkConfig {
            policy_layers: vec![16],
            critic_layers,
            tanh_on_action_mean: false,
            ..NetworkConfig::default()
        },
        seed,
        ..LearnerConfig::default()
    }
}

/// A learner for `bandit_config`'s bandit.
pub fn bandit_learner(cfg: LearnerConfig) -> Learner {
    Learner::new(cfg, bandit_dims(), Device::Cpu).unwrap()
}

/// The bandit's sizes: one observation, a 1-D continuous action, rewards right and left.
pub fn bandit_dims() -> LearnerDims {
    LearnerDims {
        action_bounds: None,
        obs_dim: 1,
        action: ActionKind::Continuous { dim: 1 },
        reward_names: vec!["right".into(), "left".into()],
        obs_leaves: Vec::new(),
    }
}
