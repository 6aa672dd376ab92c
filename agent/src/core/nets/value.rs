//! Per-objective state-value critics V_k(s) for MO-V-MPO (appendix D.1, eq. 21) and
//! the single V of scalarized V-MPO.
//!
//! A shared LayerNorm MLP of the first `critic_shared_layers` sizes of
//! `critic_layers`, then one head per objective with the remaining sizes and a final
//! Linear to one value. A.3: MO-V-MPO shares (1024, 1024) and has one 1024 layer per
//! objective; V-MPO's three-layer 1024 MLP is the same layout with C = 1.
//!
//! A population's value nets (`with_members`) are stacked along a member axis, as
//! its policies and Q critics are (docs/design.md, "Populations").
//!
//! Shape legend: P members, N states, O observation size, C heads.

use super::heads::HeadStack;
use super::mlp::{LayerNormMlp, Members};
use crate::core::learner_config::NetworkConfig;
use tch::{Tensor, nn};

/// C value heads on a shared torso.
#[derive(Debug)]
pub struct ValueNet {
    torso: LayerNormMlp,
    heads: HeadStack,
}

impl ValueNet {
    /// Parameters under `p` (`shared/..`, `heads/linear_i`).
    pub fn new(p: &nn::Path, cfg: &NetworkConfig, obs_dim: i64, num_heads: i64) -> Self {
        Self::with_members(p, cfg, obs_dim, num_heads, Members::ONE)
    }

    /// As `new`, for `members` networks.
    pub fn with_members(
        p: &nn::Path,
        cfg: &NetworkConfig,
        obs_dim: i64,
        num_heads: i64,
        members: Members,
    ) -> Self {
        let shared = cfg.critic_shared_layers;
        let layers = &cfg.critic_layers;
        let torso =
            LayerNormMlp::with_members(&(p / "shared"), obs_dim, &layers[..shared], members);
        let heads =
            HeadStack::with_members(&(p / "heads"), num_heads, &layers[shared - 1..], 0, members);
        Self { torso, heads }
    }

    /// # Shapes
    /// `obs [N, O] -> [N, C]`.
    pub fn forward(&self, obs: &Tensor) -> Tensor {
        self.heads.forward(&self.torso.forward(obs), None)
    }

    /// Every member's values on its own states.
    /// # Shapes
    /// `obs [P, N, O] -> [P, N, C]`.
    pub fn forward_members(&self, obs: &Tensor) -> Tensor {
        self.heads
            .forward_members(&self.torso.forward_members(obs), None)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::{Device, Kind};

    #[test]
    fn heads_share_the_torso_and_differ_after_it() {
        let cfg = NetworkConfig {
            critic_layers: vec![16, 12, 8],
            critic_shared_layers: 2,
            ..NetworkConfig::default()
        };
        let vs = nn::VarStore::new(Device::Cpu);
        let v = ValueNet::new(&vs.root(), &cfg, 5, 3);
        let out = v.forward(&Tensor::randn([7, 5], (Kind::Float, Device::Cpu)));
        assert_eq!(out.size(), vec![7, 3]);
        let names: Vec<String> = vs.variables().into_keys().collect();
        assert!(
            names.iter().any(|n| n == "shared.linear_1.weight"),
            "{names:?}"
        );
        let w = &vs.variables()["heads.linear_0.weight"];
        assert_eq!(w.size(), vec![3, 12, 8], "one [12 -> 8] layer per head");
    }
}
