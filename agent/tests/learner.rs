//! Full learner steps on small networks: both action kinds, MO-MPO and scalarized MPO,
//! closed-form action norm, and batch validation.

mod common;

use common::{
    continuous_learner, continuous_learner_with, discrete_scalarized_learner, random_batch,
};
use tch::{Device, Kind, Tensor};

#[test]
fn continuous_mompo_step_fits_the_critic_and_keeps_duals_positive() {
    tch::set_num_threads(1);
    // gamma = 0: the Retrace target is the reward itself, a fixed regression target.
    let mut learner = continuous_learner_with(|cfg| {
        cfg.mpo.discount = 0.0;
        cfg.mpo.learning_rate = 1e-2;
    });
    assert_eq!(learner.objectives().critic_names, vec!["task".to_string()]);
    let batch = random_batch(&learner, 11);
    let first = learner.step(&batch).unwrap();
    assert_eq!(
        (
            first.critic_loss.len(),
            first.temperature.len(),
            first.alpha.len()
        ),
        (1, 2, 2)
    );
    // Closed-form action norm: Q = -||a||_2 <= 0, and its mean is about -E||a||.
    assert!(first.q_mean[1] < 0.0);
    let mut last = first.clone();
    for _ in 0..100 {
        last = learner.step(&batch).unwrap();
    }
    assert_eq!(last.step, 101);
    assert!(
        last.critic_loss[0] < 0.5 * first.critic_loss[0],
        "critic loss {:?} -> {:?}",
        first.critic_loss,
        last.critic_loss
    );
    assert!(
        last.temperature
            .iter()
            .chain(&last.alpha)
            .all(|v| v.is_finite() && *v > 0.0),
        "{last:?}"
    );
}

#[test]
fn discrete_scalarized_step_uses_one_critic_and_exact_estep() {
    tch::set_num_threads(1);
    let mut learner = discrete_scalarized_learner(10_000);
    let batch = random_batch(&learner, 12);
    let stats = learner.step(&batch).unwrap();
    assert_eq!(
        (
            stats.critic_loss.len(),
            stats.temperature.len(),
            stats.alpha.len(),
            stats.policy_kl.len()
        ),
        (1, 1, 1, 1)
    );
    assert!(stats.estep_kl[0] >= 0.0);
    // With the target networks fixed (the period is longer than the test), the critic
    // regresses onto fixed Retrace targets, so its loss must fall. (With the shared
    // test config's period of 4, gamma = 0.999 bootstrapping on a random batch makes
    // the targets chase the critic, and the loss need not fall.)
    for _ in 0..150 {
        learner.step(&batch).unwrap();
    }
    let after = learner.step(&batch).unwrap();
    assert!(
        after.critic_loss[0] < stats.critic_loss[0],
        "{:?} -> {:?}",
        stats.critic_loss,
        after.critic_loss
    );
    let act = learner.act(&Tensor::zeros([5, 3], (Kind::Float, Device::Cpu)), true);
    assert_eq!(act.actions.kind(), Kind::Int64);
}

#[test]
fn mis_shaped_batch_is_rejected_with_the_shapes() {
    let mut learner = continuous_learner();
    let mut batch = random_batch(&learner, 13);
    batch.rewards = batch.rewards.narrow(2, 0, 1);
    let msg = learner.step(&batch).unwrap_err().to_string();
    assert_eq!(
        msg,
        "SnippetBatch.rewards: expected [3, 16, 2] Float, got [3, 16, 1] Float"
    );
}

#[test]
fn policy_snapshot_drives_an_actor_policy() {
    let learner = continuous_learner();
    let mut actor =
        agent::nets::ActorPolicy::new(&learner.config().network, learner.dims(), Device::Cpu);
    actor.load(&learner.policy_snapshot()).unwrap();
    let obs = Tensor::randn([4, 3], (Kind::Float, Device::Cpu));
    assert!(
        actor
            .act(&obs, true)
            .actions
            .equal(&learner.act(&obs, true).actions)
    );
    let mut wrong = learner.policy_snapshot();
    wrong.tensors.pop();
    assert!(
        actor
            .load(&wrong)
            .unwrap_err()
            .to_string()
            .contains("missing")
    );
}
