//! Checkpoint round trip: a learner restored from disk acts and learns exactly like
//! the one that was saved (networks, targets, Adam moments, duals, step counter).

mod common;

use agent::algo::MoMpoLearner;
use common::{continuous_learner, random_batch};
use tch::{Device, Kind, Tensor};

#[test]
fn round_trip_gives_identical_outputs_and_next_step() {
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

    let mut restored = MoMpoLearner::load_checkpoint(&path, Device::Cpu).unwrap();
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
    let err = MoMpoLearner::load_checkpoint(std::path::Path::new("/nonexistent/ckpt"), Device::Cpu)
        .unwrap_err();
    assert!(
        err.to_string().contains("/nonexistent/ckpt/state.json"),
        "{err}"
    );
}
