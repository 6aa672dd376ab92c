//! One full MO-V-MPO learner step at the humanoid mocap size (A.3, Table 5):
//! obs 2722 (dm_control's observables: 2490 reference, 232 proprioceptive, as
//! `humanoid-mocap` with `dict_observation` serves them), act 56, K = 5 learned
//! objectives, B = 128 unrolls of T = 32 (N = 4096 pairs), the mocap policy
//! (encoder 1024x2, latent 60, policy 1024x2) and critics (shared 1024x2, one 1024
//! layer per objective).
//!
//! The step computes: the five value heads on (T+1)B = 4224 states, T-step targets,
//! the critic update; top-k weights and temperature duals; online and target policy
//! on the 4096 taken pairs, the decoupled fit, backward, Adam on the policy and the
//! duals. Timed: median of `--steps` (default 10) after 2 warm-up steps. Runs on CUDA
//! when libtorch sees a GPU.
//!
//! Run: `cargo bench -p agent --bench vmpo_step [-- --batch 128 --steps 10]`.
#![allow(clippy::print_stdout, reason = "a benchmark reports on stdout")]

mod common;

use agent::core::algo::{Learner, LearnerDims, SnippetBatch};
use agent::core::learner_config::{
    Algorithm, Architecture, LearnerConfig, NetworkConfig, ObjectiveConfig, ObjectiveSource,
};
use agent::core::nets::{ActionKind, ObsLeaf};
use tch::{Kind, Tensor};

const OBJECTIVES: [&str; 5] = ["com", "vel", "app", "quat", "trunc"];
const REFERENCE: i64 = 2490;
const PROPRIO: i64 = 232;
const ACT: i64 = 56;

fn main() {
    agent::core::device::tune_allocator();
    let threads = agent::core::device::configure_threads(None);
    let device = agent::core::device::learner_device();
    let mut cfg = LearnerConfig {
        algorithm: Algorithm::MoVmpo,
        objectives: OBJECTIVES
            .iter()
            .map(|n| ObjectiveConfig {
                name: (*n).into(),
                epsilon: 0.1,
                source: ObjectiveSource::Learned,
            })
            .collect(),
        network: NetworkConfig {
            policy_layers: vec![1024, 1024],
            critic_layers: vec![1024, 1024, 1024],
            critic_shared_layers: 2,
            tanh_on_action_mean: false,
            min_variance: 1e-8,
            architecture: Architecture::Mocap {
                encoder_layers: vec![1024, 1024],
                latent_dim: 60,
                reference_match: "reference".into(),
            },
            ..NetworkConfig::default()
        },
        ..LearnerConfig::default()
    };
    cfg.vmpo.batch_size = common::arg("--batch", 128);
    let steps: usize = common::arg("--steps", 10);
    let dims = LearnerDims {
        action_bounds: None,
        obs_dim: REFERENCE + PROPRIO,
        action: ActionKind::Continuous { dim: ACT },
        reward_names: OBJECTIVES.iter().map(|n| (*n).to_string()).collect(),
        obs_leaves: vec![
            ObsLeaf {
                name: "walker/proprioception".into(),
                dim: PROPRIO,
            },
            ObsLeaf {
                name: "walker/reference".into(),
                dim: REFERENCE,
            },
        ],
    };
    let (t, b) = (cfg.vmpo.unroll_length as i64, cfg.vmpo.batch_size as i64);
    let mut learner = Learner::new(cfg, dims, device).expect("valid config");
    tch::manual_seed(0);
    let opts = (Kind::Float, tch::Device::Cpu);
    let batch = SnippetBatch {
        observations: Tensor::randn([t + 1, b, REFERENCE + PROPRIO], opts),
        actions: Tensor::randn([t, b, ACT], opts).clamp(-1.0, 1.0),
        rewards: Tensor::rand([t, b, 5], opts),
        discounts: Tensor::ones([t, b], opts),
        behaviour_log_probs: Tensor::zeros([t, b], opts),
        valid: Tensor::ones([t, b], opts),
    }
    .to_device(device);
    println!(
        "vmpo_step: obs {}, act {ACT}, B {b}, T {t}, K 5, mocap policy and critics, device {device:?}, threads {threads}",
        REFERENCE + PROPRIO
    );
    let names = [
        "policy evaluation (values, targets, critic update)",
        "step 1 (top-k, weights, duals)",
        "step 2 (policy fit) + duals",
        "target update",
    ];
    let totals = common::time_steps(&mut learner, &batch, 2, steps, names);
    println!("vmpo_step_ms_median={:.1}", common::median(totals));
}
