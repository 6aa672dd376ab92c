//! Behavioural tests of MO-MPO policy improvement on a one-state bandit with a 1-D
//! continuous action and two objectives in conflict, Q_1(a) = -(a-1)^2 and
//! Q_2(a) = -(a+1)^2, given in closed form (a bandit's Q is its reward).

mod common;
mod seed;

use agent::core::algo::Learner;
use agent::core::learner_config::{Algorithm, ConditioningConfig, GridTrustRegion};
use agent::core::nets::ActionKind;
use tch::{Device, Kind, Tensor};

/// One test at a time (`common::exclusive_rng`), libtorch's generator from the test
/// seed (0 unless `MO_MPO_TEST_SEED` is set).
fn exclusive() -> std::sync::MutexGuard<'static, ()> {
    let guard = common::exclusive_rng();
    tch::manual_seed(seed::test_seed() as i64);
    guard
}

/// The learner's config seed: 1, moved by the test seed.
fn learner_seed() -> u64 {
    1 + seed::test_seed()
}

const STATES: i64 = 32;

fn bandit(eps: [f64; 2], beta_mean: f64, target_period: u64) -> Learner {
    let mut cfg = common::bandit_config(Algorithm::MoMpo, eps, vec![8], learner_seed());
    cfg.mpo.learning_rate = 3e-3;
    // Faster duals than Acme's 1e-2 so eta_k settles within a few hundred steps.
    cfg.mpo.dual_learning_rate = 0.1;
    cfg.mpo.beta_mean = beta_mean;
    cfg.mpo.target_update_period = target_period;
    common::bandit_learner(cfg)
}

fn q_values(actions: &Tensor) -> Tensor {
    let a = actions.squeeze_dim(-1);
    Tensor::stack(&[-(&a - 1.0).square(), -(&a + 1.0).square()], -1)
}

fn obs() -> Tensor {
    Tensor::zeros([STATES, 1], (Kind::Float, Device::Cpu))
}

/// Mean action of the policy averaged over the last `tail` of `steps` updates.
fn fitted_mean(learner: &mut Learner, steps: usize, tail: usize) -> f64 {
    let mut sum = 0.0;
    for i in 0..steps {
        learner.improve_policy_with(&obs(), q_values);
        if i >= steps - tail {
            sum += learner
                .act(&obs().narrow(0, 0, 1), true)
                .actions
                .double_value(&[0, 0]);
        }
    }
    sum / tail as f64
}

#[test]
fn preference_follows_the_epsilon_ratio() {
    let _guard = exclusive();
    let means: Vec<f64> = [0.5, 1.0, 4.0]
        .iter()
        .map(|ratio| fitted_mean(&mut bandit([0.01 * ratio, 0.01], 5e-3, 10), 600, 100))
        .collect();
    seed::report_figures(
        "preference_follows_the_epsilon_ratio",
        &format!("{means:.3?}"),
    );
    assert!(
        means[0] < means[1] && means[1] < means[2],
        "mean action should grow with eps1/eps2: {means:?}"
    );
    // eps1 < eps2 leans to objective 2 (a < 0), equal is a compromise, eps1 = 4 eps2 leans clearly to 1.
    // Measured (seed 0): -0.08, 0.06, 0.73; seeds 1-5: -0.13, 0.02, 0.79; -0.11, 0.05,
    // 0.79; -0.07, 0.09, 0.80; -0.03, 0.05, 0.55; -0.22, 0.02, 0.84.
    assert!(
        means[0] < 0.0 && means[1].abs() < 0.15 && means[2] > 0.3,
        "{means:?}"
    );
}

#[test]
fn zero_epsilon_objective_has_no_influence() {
    let _guard = exclusive();
    // Objective 2 (optimum -1) with eps = 0 must not pull: the policy goes to +1.
    // Measured right / left (seed 0): 1.004 / -0.997; seeds 1-5: 0.993 / -1.012,
    // 0.980 / -1.016, 0.999 / -1.017, 1.001 / -0.997, 1.010 / -0.975.
    let only_right = fitted_mean(&mut bandit([0.05, 0.0], 5e-3, 10), 800, 100);
    assert!(
        (only_right - 1.0).abs() < 0.2,
        "eps_2 = 0: expected the optimum of objective 1, got {only_right}"
    );
    let only_left = fitted_mean(&mut bandit([0.0, 0.05], 5e-3, 10), 800, 100);
    seed::report_figures(
        "zero_epsilon_objective_has_no_influence",
        &format!("right {only_right:.3} left {only_left:.3}"),
    );
    assert!(
        (only_left + 1.0).abs() < 0.2,
        "eps_1 = 0: expected the optimum of objective 2, got {only_left}"
    );
}

#[test]
fn kl_to_the_target_policy_stays_near_beta() {
    let _guard = exclusive();
    let beta = 1e-3;
    // Both objectives pull the same way at first (eps_2 small), so the trust region binds.
    let mut learner = bandit([0.1, 0.001], beta, 50);
    let mut kls = Vec::new();
    for _ in 0..300 {
        let (_, kl) = learner.improve_policy_with(&obs(), q_values);
        kls.push(f64::from(kl[0]));
    }
    let settled = &kls[100..];
    let mean = settled.iter().sum::<f64>() / settled.len() as f64;
    let max = settled.iter().cloned().fold(0.0, f64::max);
    seed::report_figures(
        "kl_to_the_target_policy_stays_near_beta",
        &format!("mean/beta {:.2} max/beta {:.2}", mean / beta, max / beta),
    );
    // The Lagrangian bounds the KL on average, not step by step: the mean over the
    // settled steps stays within [0.2, 2] beta, and no step blows past beta by an order
    // of magnitude (the collapses of issue 35 moved by 300-5,000 beta in one target
    // period). A bound of 5 beta on the max, as first written, held on seeds 0, 4 and 5
    // but not 1-3 (5.2-5.8 beta). Measured mean / max in beta: seed 0 1.15 / 4.4;
    // seeds 1-5 1.56 / 5.5, 1.70 / 5.8, 1.40 / 5.2, 1.05 / 3.5, 1.09 / 4.9; then
    // checked on seeds 6-10: 1.15 / 4.0, 1.09 / 5.1, 1.09 / 4.2, 1.11 / 4.1, 1.16 / 4.2.
    assert!(
        mean <= 2.0 * beta,
        "mean KL_mu {mean} exceeds 2 beta = {}",
        2.0 * beta
    );
    assert!(max <= 10.0 * beta, "max KL_mu {max} exceeds 10 beta");
    assert!(
        mean >= 0.2 * beta,
        "the constraint should be active, mean KL_mu = {mean}"
    );
}

/// A bandit learner's config conditioned on ε_right over `values` (ε_left fixed),
/// with the settings of `bandit`.
fn conditioned_bandit_config(
    values: &[f64],
    trust_region: GridTrustRegion,
) -> agent::core::learner_config::LearnerConfig {
    let mut cfg = common::bandit_config(Algorithm::MoMpo, [0.01, 0.01], vec![8], learner_seed());
    cfg.mpo.learning_rate = 3e-3;
    cfg.mpo.dual_learning_rate = 0.1;
    cfg.mpo.beta_mean = 5e-3;
    cfg.mpo.target_update_period = 10;
    cfg.conditioning = Some(ConditioningConfig {
        epsilon: [("right".to_string(), values.to_vec())].into(),
        relabel: true,
        trust_region,
        total_epsilon: None,
    });
    cfg
}

/// The conditioned bandit learner of `conditioned_bandit_config`.
fn conditioned_bandit(values: &[f64], trust_region: GridTrustRegion) -> Learner {
    let cfg = conditioned_bandit_config(values, trust_region);
    let dims = common::bandit_dims().with_preference_features(1);
    Learner::new(cfg, dims, Device::Cpu).unwrap()
}

#[test]
fn a_per_point_trust_region_for_discrete_actions_is_refused_by_name() {
    let cfg = conditioned_bandit_config(&[0.01, 0.1], GridTrustRegion::PerPoint);
    let mut dims = common::bandit_dims().with_preference_features(1);
    dims.action = ActionKind::Discrete { n: 4 };
    let err = Learner::new(cfg, dims, Device::Cpu)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("learner.conditioning.trust_region") && err.contains("per_point"),
        "{err}"
    );
}

#[test]
fn a_conditioned_policy_moves_with_epsilon_as_separate_runs_do() {
    let _guard = exclusive();
    let ratios = [0.5, 1.0, 4.0];
    let separate: Vec<f64> = ratios
        .iter()
        .map(|ratio| fitted_mean(&mut bandit([0.01 * ratio, 0.01], 5e-3, 10), 600, 100))
        .collect();
    // One policy for all three ratios, with the trust region shared by the grid points
    // or one per point: each update trains every state at a grid point drawn for it;
    // the mean action is read at each grid point's features.
    let values: Vec<f64> = ratios.iter().map(|r| 0.01 * r).collect();
    for trust_region in [GridTrustRegion::Shared, GridTrustRegion::PerPoint] {
        let conditioned = conditioned_means(&values, trust_region);
        seed::report_figures(
            &format!("a_conditioned_policy_moves_with_epsilon ({trust_region:?})"),
            &format!("conditioned {conditioned:.3?} separate {separate:.3?}"),
        );
        assert!(
            conditioned[0] < conditioned[1] && conditioned[1] < conditioned[2],
            "{trust_region:?}: mean action should grow with eps1/eps2: {conditioned:?} (separate runs {separate:?})"
        );
        // As the separate runs, eps1 = 4 eps2 leans clearly to objective 1. What does not
        // hold on every seed, and is not asserted: the conditioned means within 0.3 of the
        // separate runs' (it leans further at the low end: by 0.34 on seed 1), and a lean
        // to objective 2 at eps1 = eps2 / 2 (the separate runs' own lean there is -0.03 to
        // -0.22 over seeds 0-5, the conditioned policy's sign follows the seed: +0.04 on
        // seed 3). Shared trust region, conditioned / separate at the three ratios: seed 0
        // -0.32, -0.05, 0.68 / -0.08, 0.06, 0.73; seeds 1-5 -0.47, -0.15, 0.68; -0.15,
        // 0.14, 0.57; 0.04, 0.13, 0.73; -0.29, 0.02, 0.63; -0.07, 0.12, 0.74; checked on
        // seeds 6-10: -0.29, -0.06, 0.71; -0.29, -0.04, 0.77; -0.24, 0.06, 0.87; -0.04,
        // 0.23, 0.67; -0.14, 0.20, 0.81. One trust region per grid point, seeds 0-5: -0.32,
        // -0.05, 0.68; -0.47, -0.14, 0.68; -0.14, 0.14, 0.57; 0.04, 0.13, 0.74; -0.29,
        // 0.02, 0.64; -0.07, 0.12, 0.73 (the bandit's points move by similar KLs).
        assert!(conditioned[2] > 0.3, "{trust_region:?}: {conditioned:?}");
    }
}

/// The conditioned bandit's mean action at each grid point, averaged over the last
/// 100 of 600 updates.
fn conditioned_means(values: &[f64], trust_region: GridTrustRegion) -> Vec<f64> {
    let mut learner = conditioned_bandit(values, trust_region);
    let sets = match trust_region {
        GridTrustRegion::Shared => 1,
        GridTrustRegion::PerPoint => values.len(),
    };
    // The bandit's one action dimension: one alpha_mu and alpha_Sigma per set.
    assert!(
        learner
            .alpha_by_part()
            .iter()
            .all(|part| part.len() == sets)
    );
    let grid = learner.preference_grid().unwrap().clone();
    let states = Tensor::zeros([STATES, 2], (Kind::Float, Device::Cpu));
    let (steps, tail) = (600, 100);
    let mut sums = vec![0.0; values.len()];
    for i in 0..steps {
        learner.improve_policy_with(&states, q_values);
        if i >= steps - tail {
            for (g, sum) in sums.iter_mut().enumerate() {
                let obs =
                    Tensor::from_slice(&[&[0.0f32][..], &grid.features(g)].concat()).view([1, 2]);
                *sum += learner.act(&obs, true).actions.double_value(&[0, 0]);
            }
        }
    }
    sums.iter().map(|s| s / tail as f64).collect()
}

/// The trap an env's clipping sets for a Gaussian policy (issue 35, mo-halfcheetah):
/// the env executes clip(a, -1, 1), so its critic scores every sample beyond a bound
/// alike, and a mean that has left the box gets no pull back. Objective "right" is
/// first Q = a (a critic that extrapolates, or a task that pays beyond the box), which
/// drives the mean out past 1; then Q = clip(a), the executed action's, which is flat
/// out there. "left" has ε = 0 (no influence). Returns the mean after each phase.
fn clipped_bandit_means(action_penalization: Option<f64>) -> (f64, f64) {
    let mut learner = {
        let mut cfg = common::bandit_config(Algorithm::MoMpo, [0.1, 0.0], vec![8], learner_seed());
        cfg.mpo.learning_rate = 3e-3;
        cfg.mpo.dual_learning_rate = 0.1;
        cfg.mpo.beta_mean = 0.05;
        cfg.mpo.target_update_period = 10;
        cfg.mpo.action_penalization = action_penalization;
        common::bandit_learner(cfg)
    };
    let mean = |learner: &Learner| {
        learner
            .act(&obs().narrow(0, 0, 1), true)
            .actions
            .double_value(&[0, 0])
    };
    let with_right = |right: fn(&Tensor) -> Tensor| {
        move |a: &Tensor| Tensor::stack(&[right(a), a.zeros_like()], -1).squeeze_dim(-2)
    };
    for _ in 0..300 {
        learner.improve_policy_with(&obs(), with_right(|a| a.shallow_clone()));
    }
    let pushed = mean(&learner);
    for _ in 0..1500 {
        learner.improve_policy_with(&obs(), with_right(|a| a.clamp(-1.0, 1.0)));
    }
    (pushed, mean(&learner))
}

#[test]
fn the_action_penalty_pulls_a_mean_back_inside_the_bounds() {
    let _guard = exclusive();
    let (pushed, stays) = clipped_bandit_means(None);
    let (pushed_penalized, back) = clipped_bandit_means(Some(0.01));
    seed::report_figures(
        "the_action_penalty_pulls_a_mean_back_inside_the_bounds",
        &format!("off {pushed:.3} -> {stays:.3}, on {pushed_penalized:.3} -> {back:.3}"),
    );
    assert!(
        pushed > 1.5 && pushed_penalized > 1.5,
        "Q = a should push the mean out past the bound: {pushed}, {pushed_penalized}"
    );
    // Without the penalty the flat critic leaves the mean out there (it keeps at least
    // 75% of its distance past the bound: it only drifts); with it the mean comes at
    // least halfway back. As first written, with 600 steps of the flat critic instead of
    // 1,500, the penalized mean came 54-59% of the way back on seeds 0 and 3-5 but 46%
    // and 48% on seeds 1 and 2; and the unpenalized one was first held to 90%, which
    // seed 2 kept by 1% (91%). Measured pushed -> end, off / on: seed 0 6.99 -> 7.13 /
    // 3.46 -> 1.74; seeds 1-5 5.09 -> 5.06 / 2.39 -> 1.57, 5.15 -> 4.78 / 2.47 -> 1.59,
    // 5.77 -> 5.61 / 2.85 -> 1.64, 9.77 -> 9.69 / 5.23 -> 2.17, 4.59 -> 4.44 / 2.23 ->
    // 1.49; seeds 6-10 7.13 -> 7.28 / 3.40 -> 1.79, 4.99 -> 5.08 / 2.47 -> 1.52, 5.92 ->
    // 6.00 / 2.84 -> 1.56, 6.43 -> 6.37 / 3.30 -> 1.68, 6.02 -> 6.00 / 3.08 -> 1.61.
    assert!(
        stays - 1.0 > 0.75 * (pushed - 1.0),
        "no penalty: {pushed} -> {stays}"
    );
    assert!(
        back - 1.0 < 0.5 * (pushed_penalized - 1.0),
        "penalty: {pushed_penalized} -> {back}"
    );
}
