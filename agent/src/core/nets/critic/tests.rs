//! Unit tests of the critics: heads, chunked and member passes, carried columns.

use super::super::testing::{blind_carried_inputs, normal};
use super::*;
use tch::Device;

fn cfg() -> NetworkConfig {
    NetworkConfig {
        critic_layers: vec![16, 8],
        ..NetworkConfig::default()
    }
}

#[test]
fn heads_are_independent_networks_on_a_shared_layer() {
    let vs = nn::VarStore::new(Device::Cpu);
    let critic = MultiCritic::new(&vs.root(), &cfg(), 3, ActionKind::Continuous { dim: 2 }, 2);
    let obs = normal(&[5, 3], 7);
    let act = normal(&[4, 5, 2], 8);
    let q = critic.forward_samples(&obs, &act);
    assert_eq!(q.size(), vec![4, 5, 2]);
    let one = critic.forward(&obs, &act.get(1));
    assert!(q.get(1).allclose(&one, 1e-5, 1e-6, false));
    // Perturbing head 1's last layer changes only column 1.
    tch::no_grad(|| {
        let w = vs.variables()["heads.linear_1.bias"].shallow_clone();
        let _ = w.narrow(0, 1, 1).fill_(5.0);
    });
    let q2 = critic.forward_samples(&obs, &act);
    assert!(q2.select(2, 0).allclose(&q.select(2, 0), 1e-6, 1e-6, false));
    assert!(!q2.select(2, 1).allclose(&q.select(2, 1), 1e-3, 1e-3, false));
}

#[test]
fn untracked_chunked_samples_match_the_tracked_pass() {
    let vs = nn::VarStore::new(Device::Cpu);
    let critic = MultiCritic::new(&vs.root(), &cfg(), 3, ActionKind::Continuous { dim: 2 }, 2);
    // 6 samples x 1000 states > CHUNK_ROWS: the untracked pass runs 4 + 2 samples.
    let obs = normal(&[1000, 3], 9);
    let act = normal(&[6, 1000, 2], 10);
    let tracked = critic.forward_samples(&obs, &act);
    assert!(tracked.requires_grad());
    let untracked = tch::no_grad(|| critic.forward_samples(&obs, &act));
    assert_eq!(untracked.size(), vec![6, 1000, 2]);
    let err = (&tracked - &untracked).abs().max().double_value(&[]);
    assert!(err < 1e-5, "max difference {err}");
}

/// Two shared layers and two head layers, so that the carried columns have a
/// shared hidden layer, the shared part's output and a later head layer to reach.
fn carrying_cfg() -> NetworkConfig {
    NetworkConfig {
        critic_layers: vec![16, 12, 8],
        critic_shared_layers: 2,
        ..NetworkConfig::default()
    }
}

const OBS: i64 = 4;
const CARRY: i64 = 2;

fn carrying_critic(vs: &nn::VarStore, action: ActionKind, members: Members) -> MultiCritic {
    let cfg = carrying_cfg();
    MultiCritic::with_members(&vs.root(), &cfg, OBS, action, 2, CARRY, members)
}

/// Two carrying critics and a stacked population of two holding their parameters.
struct Population {
    singles: Vec<(nn::VarStore, MultiCritic)>,
    _stacked_vs: nn::VarStore,
    stacked: MultiCritic,
}

fn population(action: ActionKind) -> Population {
    let singles: Vec<(nn::VarStore, MultiCritic)> = (0..2)
        .map(|_| {
            let vs = nn::VarStore::new(Device::Cpu);
            let critic = carrying_critic(&vs, action, Members::ONE);
            (vs, critic)
        })
        .collect();
    let stacked_vs = nn::VarStore::new(Device::Cpu);
    let stacked = carrying_critic(&stacked_vs, action, Members::new(2).unwrap());
    let variables = stacked_vs.variables();
    for (p, (vs, _)) in singles.iter().enumerate() {
        for (name, value) in vs.variables() {
            tch::no_grad(|| variables[&name].get(p as i64).copy_(&value));
        }
    }
    Population {
        singles,
        _stacked_vs: stacked_vs,
        stacked,
    }
}

#[test]
fn carried_columns_reach_every_later_critic_layer() {
    let later = [
        "shared.linear_1.weight",
        "heads.linear_0.weight",
        "heads.linear_1.weight",
    ];
    let obs = normal(&[5, OBS], 1);
    // The same states at other preferences: only the carried columns differ.
    let other = Tensor::cat(&[obs.narrow(1, 0, OBS - CARRY), normal(&[5, CARRY], 2)], 1);
    let act = normal(&[3, 5, 2], 3);
    for keep in later {
        let vs = nn::VarStore::new(Device::Cpu);
        let critic = carrying_critic(&vs, ActionKind::Continuous { dim: 2 }, Members::ONE);
        blind_carried_inputs(&vs, keep, CARRY);
        let q = critic.forward_samples(&obs, &act);
        let q_other = critic.forward_samples(&other, &act);
        assert!(
            !q.allclose(&q_other, 1e-4, 1e-4, false),
            "{keep} alone does not see the carried columns"
        );
        blind_carried_inputs(&vs, "none", CARRY);
        let q = critic.forward_samples(&obs, &act);
        let q_other = critic.forward_samples(&other, &act);
        assert!(q.equal(&q_other), "{keep} blinded too, yet Q differs");
    }
}

#[test]
fn carrying_passes_agree_and_members_are_their_single_critics() {
    let Population {
        singles, stacked, ..
    } = population(ActionKind::Continuous { dim: 2 });
    // 6 samples x 1000 states > CHUNK_ROWS: the untracked pass runs in chunks.
    let obs = normal(&[2, 1000, OBS], 4);
    let act = normal(&[2, 6, 1000, 2], 5);
    let q = stacked.forward_samples_members(&obs, &act);
    let one = stacked.forward_members(&obs, &act.select(1, 4));
    assert!(q.select(1, 4).allclose(&one, 1e-5, 1e-6, false));
    for (p, (_, single)) in singles.iter().enumerate() {
        let (obs, act) = (obs.get(p as i64), act.get(p as i64));
        let tracked = single.forward_samples(&obs, &act);
        let untracked = tch::no_grad(|| single.forward_samples(&obs, &act));
        assert!(tracked.allclose(&untracked, 1e-5, 1e-6, false));
        assert!(q.get(p as i64).allclose(&tracked, 1e-5, 1e-6, false));
    }
}

#[test]
fn a_discrete_carrying_critic_scores_all_actions_as_single_actions() {
    let Population {
        singles, stacked, ..
    } = population(ActionKind::Discrete { n: 4 });
    let obs = normal(&[2, 5, OBS], 6);
    let all = stacked.forward_all_actions_members(&obs);
    for (p, (_, single)) in singles.iter().enumerate() {
        let obs = obs.get(p as i64);
        let a2 = single.forward(&obs, &Tensor::full([5], 2, (Kind::Int64, Device::Cpu)));
        let mine = single.forward_all_actions(&obs);
        assert!(mine.get(2).allclose(&a2, 1e-5, 1e-6, false));
        assert!(all.get(p as i64).allclose(&mine, 1e-5, 1e-6, false));
    }
}

#[test]
fn one_hot_all_actions_matches_single_actions() {
    let vs = nn::VarStore::new(Device::Cpu);
    let critic = MultiCritic::new(&vs.root(), &cfg(), 3, ActionKind::Discrete { n: 4 }, 2);
    let obs = normal(&[5, 3], 7);
    let all = critic.forward_all_actions(&obs);
    assert_eq!(all.size(), vec![4, 5, 2]);
    let a2 = critic.forward(&obs, &Tensor::full([5], 2, (Kind::Int64, Device::Cpu)));
    assert!(all.get(2).allclose(&a2, 1e-5, 1e-6, false));
}
