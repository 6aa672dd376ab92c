//! Unit tests of the preference grid, its features, relabelling and `--epsilon` parsing.

use super::*;
use crate::core::algo::QSource;
use crate::core::random::{Purpose, StreamKey};

fn objectives() -> Vec<BoundObjective> {
    ["task", "action_norm", "other"]
        .iter()
        .map(|n| BoundObjective {
            name: n.to_string(),
            epsilon: 0.1,
            source: QSource::Critic { head: 0 },
        })
        .collect()
}

fn grid() -> PreferenceGrid {
    let cfg = ConditioningConfig {
        epsilon: BTreeMap::from([
            ("action_norm".into(), vec![0.001, 0.01, 0.1]),
            ("other".into(), vec![0.5, 0.05]),
        ]),
        relabel: true,
        trust_region: Default::default(),
        total_epsilon: None,
    };
    PreferenceGrid::new(&cfg, &objectives())
}

#[test]
fn product_grid_in_objective_order_last_fastest() {
    let g = grid();
    assert_eq!(g.len(), 6);
    assert_eq!(g.num_features(), 2);
    assert_eq!(g.epsilon(0), &[0.1, 0.001, 0.5]);
    assert_eq!(g.epsilon(1), &[0.1, 0.001, 0.05]);
    assert_eq!(g.epsilon(5), &[0.1, 0.1, 0.05]);
    assert_eq!(
        g.setting(3),
        BTreeMap::from([
            ("action_norm".into(), 0.01),
            ("other".into(), 0.05),
            ("task".into(), 0.1)
        ])
    );
}

#[test]
fn features_map_log_range_to_unit_interval() {
    let g = grid();
    // action_norm: log 0.001 .. log 0.1 -> -1 .. 1, log 0.01 is the centre;
    // other: 0.05 is the smaller (-1), 0.5 the larger (+1).
    let close = |a: &[f32], b: &[f32]| a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-6);
    assert!(close(&g.features(0), &[-1.0, 1.0]));
    assert!(close(&g.features(3), &[0.0, -1.0]));
    // Off the grid: ε = 1 is one range beyond 0.1 on the log scale.
    assert!(close(&g.features_of(&[0.1, 1.0, 0.5]), &[2.0, 1.0]));
    let rows = g.append(&[7.0, 8.0], 1, &[0, 3]);
    assert_eq!(rows.len(), 6);
    assert!(close(&rows, &[7.0, -1.0, 1.0, 8.0, 0.0, -1.0]));
}

#[test]
fn settings_name_conditioned_objectives_only() {
    let g = grid();
    let eps = g
        .epsilon_for(&BTreeMap::from([("action_norm".into(), 0.02)]))
        .unwrap();
    assert_eq!(eps, vec![0.1, 0.02, 0.5]);
    let err = g
        .epsilon_for(&BTreeMap::from([("task".into(), 0.02)]))
        .unwrap_err();
    assert!(
        err.contains("\"task\" is not a conditioned objective"),
        "{err}"
    );
    assert!(
        g.epsilon_for(&BTreeMap::from([("other".into(), 0.0)]))
            .is_err()
    );
}

#[test]
fn settings_parse_from_the_command_line() {
    let s = parse_setting("task=0.1, action_norm=2e-2").unwrap();
    assert_eq!(
        s,
        BTreeMap::from([("action_norm".into(), 0.02), ("task".into(), 0.1)])
    );
    for (bad, says) in [
        ("task", "NAME=EPS"),
        ("task=x", "must be a number"),
        ("task=1,task=2", "more than once"),
        ("", "expected NAME=EPS"),
    ] {
        let err = parse_setting(bad).unwrap_err();
        assert!(err.contains(says), "{bad:?}: {err}");
    }
}

#[test]
fn state_weights_average_each_grid_point_over_its_states() {
    let g = grid();
    let table = g.epsilon_table(Device::Cpu);
    let index = Tensor::from_slice(&[0i64, 2, 2, 5, 2]);
    let p = StatePreferences::new(index, &table);
    let w = Vec::<f32>::try_from(&p.state_weight).unwrap();
    let third = 1.0 / 3.0;
    assert_eq!(w, vec![1.0, third, third, 1.0, third]);
    assert_eq!(p.epsilon.size(), vec![5, 3]);
    assert!((p.epsilon.double_value(&[3, 2]) - 0.05).abs() < 1e-7);
}

#[test]
fn relabelled_features_read_back_as_their_grid_points() {
    let g = grid();
    let table = g.feature_table(Device::Cpu);
    let obs = Tensor::zeros([3, 4, 1 + 2], (Kind::Float, Device::Cpu));
    let mut stream = StreamKey::new(3, Purpose::Replay, 0).at(0);
    let index: Vec<i64> = (0..4).map(|_| g.draw(&mut stream) as i64).collect();
    let index = Tensor::from_slice(&index);
    let relabelled = relabel(&obs, &index, &table);
    assert_eq!(relabelled.size(), vec![3, 4, 3]);
    assert_eq!(collected_index(&relabelled, &table), index);
    // Every time step of a snippet carries the snippet's features.
    assert_eq!(relabelled.get(0), relabelled.get(2));
}

#[test]
fn a_total_epsilon_rescales_every_point_keeping_its_ratios() {
    let g = grid();
    let listed = g.epsilon_table(Device::Cpu);
    assert_eq!(
        Vec::<f32>::try_from(g.estep_epsilon_table(None, Device::Cpu).flatten(0, 1)).unwrap(),
        Vec::<f32>::try_from(listed.flatten(0, 1)).unwrap()
    );
    let scaled = g.estep_epsilon_table(Some(0.2), Device::Cpu);
    for point in 0..g.len() {
        let row = Vec::<f32>::try_from(scaled.get(point as i64)).unwrap();
        let sum: f32 = row.iter().sum();
        assert!((sum - 0.2).abs() < 1e-6, "point {point}: {row:?}");
        // The same ratios as listed: each ε over the point's first.
        let eps = g.epsilon(point);
        for (k, &e) in eps.iter().enumerate() {
            let want = e / eps[0];
            let got = f64::from(row[k] / row[0]);
            assert!(
                (got - want).abs() < 1e-5 * want,
                "point {point}, {k}: {got} vs {want}"
            );
        }
    }
}
