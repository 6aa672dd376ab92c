//! Per-objective Q critics with a shared first layer (appendix A: "a separate critic is
//! trained for each objective, with a shared first layer").
//!
//! Input: observation concatenated with the action (tanh of the action when
//! `tanh_on_critic_action`, Table 2) or with a one-hot action for discrete spaces (A.2).
//! The shared first layer `Linear([obs, a]) -> LayerNorm -> tanh` is computed as
//! `W_obs obs + W_act a + b` (the same function as on the concatenation), so for M
//! sampled actions per state the observation half is computed once per state. The
//! C heads (`[C, in, out]` stacked weights) run as one batched matmul per layer, so
//! all learned objectives are evaluated in one pass.
//!
//! Shape legend: N states, M actions per state, D action dims, A discrete actions,
//! C heads (learned objectives).

use super::ActionKind;
use super::activation::elu_;
use super::heads::HeadStack;
use super::mlp::{Dense, Norm};
use crate::config::NetworkConfig;
use tch::{Device, Kind, Tensor, nn};

/// Rows per chunk of an untracked `forward_samples` (about 9 MB per activation at width
/// 500). On the development machine 4608 rows made the humanoid-size step about 10%
/// faster than one pass over all 92,160 rows, and 9216 or 18,432 rows did not help.
const CHUNK_ROWS: i64 = 4608;

/// C critic heads on a shared first layer (and `critic_shared_layers - 1` more).
#[derive(Debug)]
pub struct MultiCritic {
    obs_layer: Dense,
    action_layer: Dense,
    norm: Norm,
    shared_hidden: Vec<Dense>,
    heads: HeadStack,
    action: ActionKind,
    tanh_action: bool,
    num_heads: i64,
}

impl MultiCritic {
    /// `num_heads` = C learned objectives; parameters under `p`
    /// (`shared/{obs,action,layer_norm}`, `heads/linear_i`).
    pub fn new(
        p: &nn::Path,
        cfg: &NetworkConfig,
        obs_dim: i64,
        action: ActionKind,
        num_heads: i64,
    ) -> Self {
        let layers = &cfg.critic_layers;
        let act_dim = action.critic_input_dim();
        let fan_in = obs_dim + act_dim;
        let shared = p / "shared";
        let obs_layer = Dense::new(&(&shared / "obs"), obs_dim, layers[0], fan_in, true);
        let action_layer = Dense::new(&(&shared / "action"), act_dim, layers[0], fan_in, false);
        let norm = Norm::new(&(&shared / "layer_norm"), layers[0]);
        let n_shared = cfg.critic_shared_layers;
        let shared_hidden = layers[..n_shared]
            .windows(2)
            .enumerate()
            .map(|(i, w)| {
                Dense::new(
                    &(&shared / format!("linear_{}", i + 1)),
                    w[0],
                    w[1],
                    w[0],
                    true,
                )
            })
            .collect();
        let heads = HeadStack::new(&(p / "heads"), num_heads, &layers[n_shared - 1..]);
        Self {
            obs_layer,
            action_layer,
            norm,
            shared_hidden,
            heads,
            action,
            tanh_action: cfg.tanh_on_critic_action,
            num_heads,
        }
    }

    /// Number of heads C.
    pub fn num_heads(&self) -> i64 {
        self.num_heads
    }

    fn action_features(&self, actions: &Tensor) -> Tensor {
        match self.action {
            ActionKind::Continuous { .. } if self.tanh_action => actions.tanh(),
            ActionKind::Continuous { .. } => actions.shallow_clone(),
            ActionKind::Discrete { n } => actions.one_hot(n).to_kind(Kind::Float),
        }
    }

    /// Further shared layers, then the heads, on first-layer features. `[P, h1] -> [P, C]`.
    fn heads_forward(&self, h: &Tensor) -> Tensor {
        let mut x = h.shallow_clone();
        for layer in &self.shared_hidden {
            x = layer.forward(&x);
            elu_(&mut x);
        }
        self.heads.forward(&x)
    }

    /// Shared first layer for actions `[.., N, a]` against states `[N, obs]`.
    fn first_layer(&self, obs: &Tensor, action_features: &Tensor) -> Tensor {
        self.first_layer_from(&self.obs_layer.forward(obs), action_features)
    }

    /// As `first_layer`, with the per-state part `W_obs obs + b` `[N, h1]` given.
    fn first_layer_from(&self, per_state: &Tensor, action_features: &Tensor) -> Tensor {
        // Add the per-state part into the [.., N, h1] action part in place: at M = 20
        // samples that tensor is the largest of the step, and a second copy of it costs
        // more memory traffic than the smaller GEMM saves (Linear's backward does not
        // need its output, so the in-place add is autograd-safe).
        let mut h = self.action_layer.forward(action_features);
        if h.dim() >= 2 && h.size()[h.dim() - 2] == per_state.size()[0] {
            let _ = h.g_add_(per_state);
        } else {
            // The one-hot table of all actions is `[A, 1, h1]`: broadcast out of place.
            #[allow(
                clippy::assign_op_pattern,
                reason = "`+=` is in place and cannot broadcast"
            )]
            {
                h = h + per_state;
            }
        }
        self.norm.forward_tanh(&h)
    }

    /// Q for one action per state.
    /// # Shapes
    /// `obs [N, obs_dim]`, `actions [N, D] f32 | [N] i64 -> [N, C]`.
    pub fn forward(&self, obs: &Tensor, actions: &Tensor) -> Tensor {
        self.heads_forward(&self.first_layer(obs, &self.action_features(actions)))
    }

    /// Q for M actions per state.
    /// # Shapes
    /// `obs [N, obs_dim]`, `actions [M, N, D] f32 | [M, N] i64 -> [M, N, C]`.
    pub fn forward_samples(&self, obs: &Tensor, actions: &Tensor) -> Tensor {
        let per_state = self.obs_layer.forward(obs);
        let (m, n) = (actions.size()[0], actions.size()[1]);
        let eval = |a: &Tensor| {
            let h = self.first_layer_from(&per_state, &self.action_features(a));
            let rows = h.size()[0];
            self.heads_forward(&h.reshape([rows * n, -1]))
                .reshape([rows, n, self.num_heads])
        };
        if per_state.requires_grad() || m * n <= CHUNK_ROWS || per_state.device() != Device::Cpu {
            return eval(actions);
        }
        // Untracked (the target critic on every sample) on a CPU: a few samples at a
        // time, so that each layer's activations stay in cache between the GEMM and the
        // element-wise passes that follow it, instead of streaming the whole
        // [M N, h] tensor through memory once per pass. A GPU has no such cache to
        // keep; there chunks would only add kernel launches (20 chunks at humanoid size).
        let per_chunk = (CHUNK_ROWS / n).max(1);
        let chunks: Vec<Tensor> = (0..m)
            .step_by(per_chunk as usize)
            .map(|s| eval(&actions.narrow(0, s, per_chunk.min(m - s))))
            .collect();
        Tensor::cat(&chunks, 0)
    }

    /// Q for every discrete action (panics for continuous critics).
    /// # Shapes
    /// `obs [N, obs_dim] -> [A, N, C]`.
    pub fn forward_all_actions(&self, obs: &Tensor) -> Tensor {
        let ActionKind::Discrete { n } = self.action else {
            panic!("forward_all_actions needs a discrete action space");
        };
        let eye = Tensor::eye(n, (Kind::Float, obs.device())).unsqueeze(1);
        let h = self.first_layer(obs, &eye);
        let rows = obs.size()[0];
        self.heads_forward(&h.reshape([n * rows, -1]))
            .reshape([n, rows, self.num_heads])
    }
}

#[cfg(test)]
mod tests {
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
        let obs = Tensor::randn([5, 3], (Kind::Float, Device::Cpu));
        let act = Tensor::randn([4, 5, 2], (Kind::Float, Device::Cpu));
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
        let obs = Tensor::randn([1000, 3], (Kind::Float, Device::Cpu));
        let act = Tensor::randn([6, 1000, 2], (Kind::Float, Device::Cpu));
        let tracked = critic.forward_samples(&obs, &act);
        assert!(tracked.requires_grad());
        let untracked = tch::no_grad(|| critic.forward_samples(&obs, &act));
        assert_eq!(untracked.size(), vec![6, 1000, 2]);
        let err = (&tracked - &untracked).abs().max().double_value(&[]);
        assert!(err < 1e-5, "max difference {err}");
    }

    #[test]
    fn one_hot_all_actions_matches_single_actions() {
        let vs = nn::VarStore::new(Device::Cpu);
        let critic = MultiCritic::new(&vs.root(), &cfg(), 3, ActionKind::Discrete { n: 4 }, 2);
        let obs = Tensor::randn([5, 3], (Kind::Float, Device::Cpu));
        let all = critic.forward_all_actions(&obs);
        assert_eq!(all.size(), vec![4, 5, 2]);
        let a2 = critic.forward(&obs, &Tensor::full([5], 2, (Kind::Int64, Device::Cpu)));
        assert!(all.get(2).allclose(&a2, 1e-5, 1e-6, false));
    }
}
