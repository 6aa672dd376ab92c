//! Binding and closed-form objectives (`objectives/mod.rs`).

use super::*;

#[test]
fn the_closed_form_action_norm_is_that_of_the_executed_action() {
    // Pendulum: torque in [-2, 2]. Samples -3 and 1.7 are clipped to -1 and 1, then
    // mapped: -2 and 2; 0.25 maps to 0.5. The env's action_norm is -|u| of those.
    let pendulum = ActionBounds {
        low: vec![-2.0],
        high: vec![2.0],
    };
    let samples = Tensor::from_slice(&[-3.0f32, 0.25, 1.7]).reshape([3, 1]);
    let q = Vec::<f32>::try_from(&action_norm_q(&samples, Some(&pendulum))).unwrap();
    assert_eq!(q, vec![-2.0, -0.5, -2.0]);
    // Two dims, one unbounded (left clipped): ||(0.5 + 1.5 * 0.5, 1)|| for bounds
    // [-1, 2] (center 0.5, half-range 1.5) and sample (0.5, 4).
    let mixed = ActionBounds {
        low: vec![-1.0, f32::NEG_INFINITY],
        high: vec![2.0, f32::INFINITY],
    };
    let q = action_norm_q(&Tensor::from_slice(&[0.5f32, 4.0]), Some(&mixed));
    let want = -(1.25f64.powi(2) + 1.0).sqrt();
    assert!((q.double_value(&[]) - want).abs() < 1e-6);
    // No bounds stored: clipped to [-1, 1] only.
    let q = action_norm_q(&Tensor::from_slice(&[3.0f32, 0.0]), None);
    assert_eq!(q.double_value(&[]), -1.0);
}

fn obj(name: &str, epsilon: f64, source: ObjectiveSource) -> ObjectiveConfig {
    ObjectiveConfig {
        name: name.into(),
        epsilon,
        source,
    }
}

fn env() -> Vec<String> {
    vec!["task".into(), "action_norm".into()]
}

#[test]
fn binds_in_env_order_with_closed_form_action_norm() {
    let cfg = [
        obj("action_norm", 0.01, ObjectiveSource::ActionNorm),
        obj("task", 0.1, ObjectiveSource::Learned),
    ];
    let b = bind_names(&cfg, &env()).unwrap();
    assert_eq!(b.objectives[0].source, QSource::Critic { head: 0 });
    assert_eq!(b.objectives[1].source, QSource::ActionNorm);
    assert_eq!(b.critic_names, vec!["task".to_string()]);
    assert_eq!(b.critic_reward_weights, vec![vec![1.0], vec![0.0]]);
}

#[test]
fn names_missing_extra_and_duplicates() {
    let cfg = [
        obj("task", 0.1, ObjectiveSource::Learned),
        obj("task", 0.2, ObjectiveSource::Learned),
        obj("pain", 0.1, ObjectiveSource::Learned),
    ];
    let msg = bind_names(&cfg, &env()).unwrap_err().to_string();
    assert_eq!(
        msg,
        r#"learner.objectives must name each of the env's objectives ["task", "action_norm"] once, got ["task", "task", "pain"]: missing ["action_norm"]; not objectives of this env ["pain"]; named more than once ["task"]"#
    );
    // Only the kinds of problem that occur are named (no empty lists).
    let cfg = [
        obj("task", 0.1, ObjectiveSource::Learned),
        obj("energy", 0.1, ObjectiveSource::Learned),
    ];
    let msg = bind_names(&cfg, &env()).unwrap_err().to_string();
    assert_eq!(
        msg,
        r#"learner.objectives must name each of the env's objectives ["task", "action_norm"] once, got ["task", "energy"]: missing ["action_norm"]; not objectives of this env ["energy"]"#
    );
}

#[test]
fn vmpo_rejects_closed_form_objectives_and_mocap_needs_named_leaves() {
    use crate::core::learner_config::{Algorithm, Architecture};
    use crate::core::nets::ObsLeaf;
    let mut cfg = LearnerConfig {
        algorithm: Algorithm::MoVmpo,
        objectives: vec![
            obj("task", 0.1, ObjectiveSource::Learned),
            obj("action_norm", 0.1, ObjectiveSource::ActionNorm),
        ],
        ..LearnerConfig::default()
    };
    let mut dims = LearnerDims {
        action_bounds: None,
        obs_dim: 4,
        action: ActionKind::Continuous { dim: 2 },
        reward_names: env(),
        obs_leaves: vec![ObsLeaf {
            name: String::new(),
            dim: 4,
        }],
    };
    let msg = bind_config(&cfg, &dims).unwrap_err().to_string();
    assert!(
        msg.contains(r#"objective "action_norm""#) && msg.contains("V-MPO"),
        "{msg}"
    );
    cfg.objectives[1].source = ObjectiveSource::Learned;
    bind_config(&cfg, &dims).unwrap();
    cfg.network.architecture = Architecture::Mocap {
        encoder_layers: vec![8],
        latent_dim: 2,
        reference_match: "reference".into(),
    };
    let msg = bind_config(&cfg, &dims).unwrap_err().to_string();
    assert!(
        msg.starts_with("network.architecture.reference_match must be"),
        "{msg}"
    );
    assert!(msg.ends_with(r#"got [""]"#), "{msg}");
    dims.obs_leaves = vec![
        ObsLeaf {
            name: "walker/joints".into(),
            dim: 1,
        },
        ObsLeaf {
            name: "walker/reference_pos".into(),
            dim: 3,
        },
    ];
    bind_config(&cfg, &dims).unwrap();
}

fn declared(name: &str, closed_form: ClosedForm) -> ObjectiveSpec {
    ObjectiveSpec {
        name: name.into(),
        description: String::new(),
        min: -1.0,
        max: 0.0,
        scale: 1.0,
        closed_form,
    }
}

#[test]
fn a_closed_form_source_needs_the_envs_declaration() {
    let cfg = [
        obj("reach", 0.1, ObjectiveSource::Learned),
        obj("energy", 0.01, ObjectiveSource::ActionNorm),
    ];
    let env = |energy| {
        vec![
            declared("reach", ClosedForm::None),
            declared("energy", energy),
        ]
    };
    bind(&cfg, &env(ClosedForm::ActionNorm)).unwrap();
    let msg = bind(&cfg, &env(ClosedForm::None)).unwrap_err().to_string();
    assert_eq!(
        msg,
        r#"learner.objectives.1.source: source = "action_norm" computes objective "energy" in closed form, which needs the env to declare closed_form = action_norm for it; the env declares closed_form = none (use source = "learned")"#
    );
    // A server older than the declaration: refused, and the message says why.
    let msg = bind(&cfg, &env(ClosedForm::Undeclared))
        .unwrap_err()
        .to_string();
    assert!(
        msg.contains("the env declares nothing (the field is unset): its server is older than ObjectiveSpec.closed_form"),
        "{msg}"
    );
    let msg = bind(&cfg, &env(ClosedForm::Unrecognized(7)))
        .unwrap_err()
        .to_string();
    assert!(
        msg.contains("closed_form = 7 (unknown to this agent)"),
        "{msg}"
    );
    // Learned sources need nothing declared, so an old server still trains them.
    let learned = [
        obj("reach", 0.1, ObjectiveSource::Learned),
        obj("energy", 0.01, ObjectiveSource::Learned),
    ];
    bind(&learned, &env(ClosedForm::Undeclared)).unwrap();
    // The scalarized baselines ignore `objectives`: nothing to refuse.
    let scalarized = LearnerConfig {
        algorithm: crate::core::learner_config::Algorithm::ScalarizedMpo {
            epsilon: 0.1,
            weights: Vec::new(),
        },
        objectives: cfg.to_vec(),
        ..LearnerConfig::default()
    };
    check_declared(&scalarized, &env(ClosedForm::None)).unwrap();
    let mompo = LearnerConfig {
        algorithm: crate::core::learner_config::Algorithm::MoMpo,
        ..scalarized
    };
    assert!(check_declared(&mompo, &env(ClosedForm::None)).is_err());
}

#[test]
fn the_out_of_bounds_penalty_is_the_distance_to_the_box() {
    // Inside the box: 0. Outside: the Euclidean distance to its nearest point,
    // ||(2 - 1, -1.5 + 1)|| for (2, -1.5); a sample out in one dimension only
    // counts that dimension.
    let samples = Tensor::from_slice(&[0.5f32, -1.0, 2.0, -1.5, 0.0, 4.0]).reshape([3, 2]);
    let q = Vec::<f32>::try_from(&out_of_bounds_q(&samples)).unwrap();
    let want = [0.0, -(1.25f32.sqrt()), -3.0];
    for (got, want) in q.iter().zip(want) {
        assert!((got - want).abs() < 1e-6, "{q:?}");
    }
}

#[test]
fn action_penalization_appends_one_closed_form_objective_after_the_envs() {
    use crate::core::learner_config::Algorithm;
    let dims = |action, names: &[&str]| LearnerDims {
        action_bounds: None,
        obs_dim: 3,
        action,
        reward_names: names.iter().map(|n| n.to_string()).collect(),
        obs_leaves: Vec::new(),
    };
    let continuous = dims(ActionKind::Continuous { dim: 2 }, &["task", "action_norm"]);
    let mut cfg = LearnerConfig {
        objectives: vec![
            obj("task", 0.1, ObjectiveSource::Learned),
            obj("action_norm", 0.01, ObjectiveSource::ActionNorm),
        ],
        ..LearnerConfig::default()
    };
    assert_eq!(
        bind_config(&cfg, &continuous).unwrap().names(),
        ["task", "action_norm"]
    );
    cfg.mpo.action_penalization = Some(1e-3);
    let b = bind_config(&cfg, &continuous).unwrap();
    assert_eq!(b.names(), ["task", "action_norm", ACTION_PENALTY]);
    assert_eq!(b.objectives[2].source, QSource::OutOfBounds);
    assert_eq!(b.objectives[2].epsilon, 1e-3);
    // No critic head for it.
    assert_eq!(b.critic_names, ["task"]);
    // Scalarized MPO: after its one objective, as Acme's MPO has it.
    let scalarized = LearnerConfig {
        algorithm: Algorithm::ScalarizedMpo {
            epsilon: 0.1,
            weights: vec![
                ObjectiveWeight {
                    name: "task".into(),
                    weight: 1.0,
                },
                ObjectiveWeight {
                    name: "action_norm".into(),
                    weight: 0.0,
                },
            ],
        },
        ..cfg.clone()
    };
    assert_eq!(
        bind_config(&scalarized, &continuous).unwrap().names(),
        ["scalarized", ACTION_PENALTY]
    );
    // Refused, naming the field: V-MPO, discrete actions, an env objective of that name.
    let mut learned = cfg.clone();
    learned.objectives[1].source = ObjectiveSource::Learned;
    let vmpo = LearnerConfig {
        algorithm: Algorithm::MoVmpo,
        ..learned.clone()
    };
    let refusals = [
        bind_config(&vmpo, &continuous),
        bind_config(
            &learned,
            &dims(ActionKind::Discrete { n: 4 }, &["task", "action_norm"]),
        ),
        bind_config(
            &LearnerConfig {
                objectives: vec![
                    obj("task", 0.1, ObjectiveSource::Learned),
                    obj(ACTION_PENALTY, 0.1, ObjectiveSource::Learned),
                ],
                ..cfg.clone()
            },
            &dims(ActionKind::Continuous { dim: 2 }, &["task", ACTION_PENALTY]),
        ),
    ];
    for (result, why) in refusals.into_iter().zip(["V-MPO", "discrete", "named"]) {
        let msg = result.unwrap_err().to_string();
        assert!(
            msg.starts_with("mpo.action_penalization must be unset") && msg.contains(why),
            "{msg}"
        );
    }
    cfg.mpo.action_penalization = Some(0.0);
    let msg = bind_config(&cfg, &continuous).unwrap_err().to_string();
    assert_eq!(
        msg,
        "mpo.action_penalization must be an ε > 0 when set, got 0.0"
    );
}

#[test]
fn scalarized_uses_weights_in_env_order() {
    let w = [
        ObjectiveWeight {
            name: "action_norm".into(),
            weight: 0.1,
        },
        ObjectiveWeight {
            name: "task".into(),
            weight: 0.9,
        },
    ];
    let b = bind_scalarized(0.1, &w, &env()).unwrap();
    assert_eq!(b.critic_reward_weights, vec![vec![0.9], vec![0.1]]);
    assert_eq!(b.objectives.len(), 1);
}
