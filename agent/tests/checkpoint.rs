//! Checkpoint round trip: a learner restored from disk acts and learns exactly like
//! the one that was saved (networks, targets, Adam moments, duals, step counter).

mod common;

use agent::core::algo::Learner;
use common::{continuous_learner, movmpo_mocap_learner, random_batch};
use tch::{Device, Kind, Tensor};

/// Three steps, a checkpoint in `dir`, and the restored learner, checked to act alike.
fn trained_and_restored(mut learner: Learner, dir: &std::path::Path) -> (Learner, Learner) {
    for seed in 0..3 {
        let batch = random_batch(&learner, seed);
        learner.step(&batch).unwrap();
    }
    let path = dir.join("ckpt");
    learner.save_checkpoint(&path).unwrap();
    let restored = Learner::load_checkpoint(&path, Device::Cpu).unwrap();
    assert_eq!(restored.step_count(), 3);
    assert_eq!(restored.policy_snapshot(), learner.policy_snapshot());
    let obs = Tensor::randn([7, 3], (Kind::Float, Device::Cpu));
    assert!(
        restored
            .act(&obs, true)
            .actions
            .equal(&learner.act(&obs, true).actions)
    );
    (learner, restored)
}

/// One step of each on the same batch and random stream must report the same.
fn step_alike(
    a: &mut Learner,
    b: &mut Learner,
    batch: &agent::core::algo::SnippetBatch,
    seed: i64,
) -> Vec<f32> {
    tch::manual_seed(seed);
    let x = a.step(batch).unwrap();
    tch::manual_seed(seed);
    let y = b.step(batch).unwrap();
    assert_eq!(
        (
            x.step,
            &x.critic_loss,
            &x.temperature,
            &x.alpha,
            &x.policy_kl
        ),
        (
            y.step,
            &y.critic_loss,
            &y.temperature,
            &y.alpha,
            &y.policy_kl
        )
    );
    x.critic_loss
}

#[test]
fn round_trip_gives_identical_outputs_and_next_step() {
    let _rng = common::exclusive_rng();
    tch::set_num_threads(1);
    let dir = tempfile::tempdir().unwrap();
    let (mut learner, mut restored) = trained_and_restored(continuous_learner(), dir.path());
    // Saving again replaces the directory atomically and leaves no temporaries.
    learner.save_checkpoint(&dir.path().join("ckpt")).unwrap();
    let names: Vec<String> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(names, vec!["ckpt".to_string()]);

    let batch = random_batch(&learner, 99);
    step_alike(&mut learner, &mut restored, &batch, 1234);
    assert_eq!(restored.policy_snapshot(), learner.policy_snapshot());
    // Step 5 comes after a target update (period 4): the copied targets agree too.
    step_alike(&mut learner, &mut restored, &batch, 77);
}

#[test]
fn missing_checkpoint_names_the_path() {
    let _rng = common::exclusive_rng();
    let err = Learner::load_checkpoint(std::path::Path::new("/nonexistent/ckpt"), Device::Cpu)
        .unwrap_err();
    assert!(
        err.to_string().contains("/nonexistent/ckpt/state.json"),
        "{err}"
    );
}

#[test]
fn movmpo_with_the_mocap_torso_round_trips() {
    let _rng = common::exclusive_rng();
    tch::set_num_threads(1);
    let dir = tempfile::tempdir().unwrap();
    // The deterministic action uses the latent's mean, so the restored one matches.
    let (mut learner, mut restored) = trained_and_restored(movmpo_mocap_learner(), dir.path());
    let batch = random_batch(&learner, 99);
    let critic_loss = step_alike(&mut learner, &mut restored, &batch, 77);
    assert_eq!(critic_loss.len(), 2, "one value head per objective");
}

#[test]
fn per_dimension_multipliers_round_trip() {
    let _rng = common::exclusive_rng();
    tch::set_num_threads(1);
    let dir = tempfile::tempdir().unwrap();
    let learner = common::continuous_learner_with(|cfg| {
        cfg.mpo.kl_constraint = agent::core::learner_config::KlConstraint::PerDimension;
    });
    let (mut learner, mut restored) = trained_and_restored(learner, dir.path());
    // One alpha_mu and one alpha_Sigma per action dimension (D = 2), and the
    // dimensions have moved apart: each follows its own KL.
    let alpha = learner.alpha_by_part();
    assert_eq!(alpha.iter().map(Vec::len).collect::<Vec<_>>(), vec![2, 2]);
    assert_ne!(alpha[0][0], alpha[0][1]);
    assert_eq!(restored.alpha_by_part(), alpha);
    let batch = random_batch(&learner, 99);
    step_alike(&mut learner, &mut restored, &batch, 5);
    assert_eq!(restored.alpha_by_part(), learner.alpha_by_part());
}

#[test]
fn movmpo_per_dimension_multipliers_round_trip() {
    let _rng = common::exclusive_rng();
    tch::set_num_threads(1);
    let dir = tempfile::tempdir().unwrap();
    // MO-V-MPO fits its policy through the same trust region, so the option applies.
    let learner = common::movmpo_mocap_learner_with(|cfg| {
        cfg.vmpo.kl_constraint = agent::core::learner_config::KlConstraint::PerDimension;
    });
    let (mut learner, mut restored) = trained_and_restored(learner, dir.path());
    let alpha = learner.alpha_by_part();
    assert_eq!(alpha.iter().map(Vec::len).collect::<Vec<_>>(), vec![2, 2]);
    assert_eq!(restored.alpha_by_part(), alpha);
    let batch = random_batch(&learner, 99);
    step_alike(&mut learner, &mut restored, &batch, 5);
    assert_eq!(restored.alpha_by_part(), learner.alpha_by_part());
}

/// `agent eval --checkpoint` on a checkpoint outside a run folder names the config it
/// looked for, instead of reading a `config.toml` from the working directory.
#[tokio::test]
async fn eval_of_a_checkpoint_without_its_run_config_names_the_missing_file() {
    let dir = tempfile::tempdir().unwrap();
    // <dir>/copied/checkpoints/step_3: the run folder would be <dir>/copied.
    let ckpt = dir.path().join("copied/checkpoints/step_3");
    continuous_learner().save_checkpoint(&ckpt).unwrap();
    let err = agent::runtime::eval::evaluate_checkpoint(
        &ckpt,
        &["127.0.0.1:1".into()],
        &agent::env::connection::ConnectionConfig::default(),
        1,
        None,
    )
    .await
    .unwrap_err()
    .to_string();
    let wanted = dir.path().join("copied/config.toml");
    assert!(
        err.starts_with("--checkpoint must be")
            && err.contains(&format!("looked for {}", wanted.display()))
            && err.ends_with(&format!("got {}", ckpt.display())),
        "{err}"
    );
}
