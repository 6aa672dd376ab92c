//! Checkpoint round trip: a learner restored from disk acts and learns exactly like
//! the one that was saved (networks, targets, Adam moments, duals, step counter).

mod common;

use agent::algo::Learner;
use common::{continuous_learner, movmpo_mocap_learner, random_batch};
use tch::{Device, Kind, Tensor};

/// The round trips seed libtorch's process-global RNG between two steps that must
/// match; holding this keeps the tests of this binary from interleaving.
static RNG: std::sync::Mutex<()> = std::sync::Mutex::new(());

#[test]
fn round_trip_gives_identical_outputs_and_next_step() {
    let _guard = RNG.lock().unwrap_or_else(|e| e.into_inner());
    tch::set_num_threads(1);
    let mut learner = continuous_learner();
    for seed in 0..3 {
        let batch = random_batch(&learner, seed);
        learner.step(&batch).unwrap();
    }
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("ckpt");
    learner.save_checkpoint(&path).unwrap();
    // Saving again replaces the directory atomically and leaves no temporaries.
    learner.save_checkpoint(&path).unwrap();
    let names: Vec<String> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(names, vec!["ckpt".to_string()]);

    let mut restored = Learner::load_checkpoint(&path, Device::Cpu).unwrap();
    assert_eq!(restored.step_count(), 3);
    let obs = Tensor::randn([7, 3], (Kind::Float, Device::Cpu));
    assert!(
        restored
            .act(&obs, true)
            .actions
            .equal(&learner.act(&obs, true).actions)
    );
    assert_eq!(restored.policy_snapshot(), learner.policy_snapshot());

    let batch = random_batch(&learner, 99);
    tch::manual_seed(1234);
    let a = learner.step(&batch).unwrap();
    tch::manual_seed(1234);
    let b = restored.step(&batch).unwrap();
    assert_eq!(
        (
            a.step,
            &a.critic_loss,
            &a.temperature,
            &a.alpha,
            &a.policy_kl
        ),
        (
            b.step,
            &b.critic_loss,
            &b.temperature,
            &b.alpha,
            &b.policy_kl
        )
    );
    assert_eq!(restored.policy_snapshot(), learner.policy_snapshot());
    // Step 4 is a target-update step (period 4): the copied targets agree too.
    tch::manual_seed(77);
    let a = learner.step(&batch).unwrap();
    tch::manual_seed(77);
    let b = restored.step(&batch).unwrap();
    assert_eq!(a.critic_loss, b.critic_loss);
}

#[test]
fn missing_checkpoint_names_the_path() {
    let err = Learner::load_checkpoint(std::path::Path::new("/nonexistent/ckpt"), Device::Cpu)
        .unwrap_err();
    assert!(
        err.to_string().contains("/nonexistent/ckpt/state.json"),
        "{err}"
    );
}

#[test]
fn movmpo_with_the_mocap_torso_round_trips() {
    let _guard = RNG.lock().unwrap_or_else(|e| e.into_inner());
    tch::set_num_threads(1);
    let mut learner = movmpo_mocap_learner();
    for seed in 0..3 {
        let batch = random_batch(&learner, seed);
        learner.step(&batch).unwrap();
    }
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("ckpt");
    learner.save_checkpoint(&path).unwrap();
    let mut restored = Learner::load_checkpoint(&path, Device::Cpu).unwrap();
    assert_eq!(restored.policy_snapshot(), learner.policy_snapshot());
    let obs = Tensor::randn([7, 3], (Kind::Float, Device::Cpu));
    assert!(restored.act(&obs, true).actions.equal(&learner.act(&obs, true).actions), "latent mean is deterministic");
    let batch = random_batch(&learner, 99);
    tch::manual_seed(77);
    let a = learner.step(&batch).unwrap();
    tch::manual_seed(77);
    let b = restored.step(&batch).unwrap();
    assert_eq!((a.step, &a.critic_loss, &a.temperature, &a.policy_kl), (b.step, &b.critic_loss, &b.temperature, &b.policy_kl));
    assert_eq!(a.critic_loss.len(), 2, "one value head per objective");
}
