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
//! Population training (`mlp/mod.rs`): with P members the layers are stacked and the
//! `*_members` passes take and return member-first tensors. Untracked passes over
//! many rows run a few members at a time on a CPU (`MEMBER_CHUNK_VALUES`), for the
//! same reason `forward_samples` chunks samples; one member alone runs exactly the
//! single-network pass.
//!
//! An ε-conditioned critic may carry its preference features (the observation's last
//! F columns) to the input of every layer after the first, heads included
//! (`network.critic_preference`), so that Q at a preference need not recover the
//! preference from the first layer's LayerNorm, which normalises it together with
//! the observation and the action.
//!
//! Shape legend: P members, N states, M actions per state, D action dims, A discrete
//! actions, C heads (learned objectives), F carried features.

use super::ActionKind;
use super::activation::elu_;
use super::heads::HeadStack;
use super::mlp::{Dense, Members, Norm, append_carried};
use crate::core::learner_config::NetworkConfig;
use tch::{Device, Kind, Tensor, nn};

/// Rows per chunk of an untracked `forward_samples` (about 9 MB per activation at width
/// 500). On the development machine 4608 rows made the humanoid-size step about 10%
/// faster than one pass over all 92,160 rows, and 9216 or 18,432 rows did not help.
const CHUNK_ROWS: i64 = 4608;

/// Values per activation (rows x heads x width) that an untracked member chunk may
/// hold on a CPU. Stacking all members of a Deep Sea Treasure population made the
/// target critic's pass memory-bound (its activations `[P, C, A N, 128]` fell out of
/// cache: ELU and the bias add ran 2x slower per value than one member's). Measured
/// with `population_step` (DST, P = 6 / 16, one thread): all members at once 0.94 /
/// 0.92 of the singles' speed, 2^20 values 1.11 / 1.18, 2^18 (one member's
/// `[2, 1024, 128]`) 1.63 / 1.42, 2^16 1.46 / 1.39. With (64, 64) critics (one member
/// 2^17 values) the DST step at P = 5 took 9.1 ms in chunks of two members (2^18),
/// 7.7-8.3 ms one member at a time (2^17) and 11.5 ms in chunks of eight (2^20);
/// splitting one member's actions further did not help.
const MEMBER_CHUNK_VALUES: i64 = 1 << 17;

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
    members: Members,
    /// The widest layer (sizes the member chunks of untracked passes).
    widest: i64,
    /// Trailing observation columns carried to every layer after the first.
    carry: i64,
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
        Self::with_members(p, cfg, obs_dim, action, num_heads, 0, Members::ONE)
    }

    /// As `new`, for `members` networks that carry the last `carry` observation
    /// columns to every layer after the first.
    pub fn with_members(
        p: &nn::Path,
        cfg: &NetworkConfig,
        obs_dim: i64,
        action: ActionKind,
        num_heads: i64,
        carry: i64,
        members: Members,
    ) -> Self {
        assert!(
            (0..=obs_dim).contains(&carry),
            "carry {carry} of {obs_dim} observation columns"
        );
        let layers = &cfg.critic_layers;
        let act_dim = action.critic_input_dim();
        let fan_in = obs_dim + act_dim;
        let shared = p / "shared";
        let dense = |path: &nn::Path, input, output, fan_in, bias| {
            Dense::with_members(path, input, output, fan_in, bias, members)
        };
        let obs_layer = dense(&(&shared / "obs"), obs_dim, layers[0], fan_in, true);
        let action_layer = dense(&(&shared / "action"), act_dim, layers[0], fan_in, false);
        let norm = Norm::with_members(&(&shared / "layer_norm"), layers[0], members);
        let n_shared = cfg.critic_shared_layers;
        let shared_hidden = layers[..n_shared]
            .windows(2)
            .enumerate()
            .map(|(i, w)| {
                let path = &shared / format!("linear_{}", i + 1);
                dense(&path, w[0] + carry, w[1], w[0] + carry, true)
            })
            .collect();
        let mut sizes = layers[n_shared - 1..].to_vec();
        sizes[0] += carry;
        let heads = HeadStack::with_members(&(p / "heads"), num_heads, &sizes, carry, members);
        Self {
            obs_layer,
            action_layer,
            norm,
            shared_hidden,
            heads,
            action,
            tanh_action: cfg.tanh_on_critic_action,
            num_heads,
            members,
            widest: *layers.iter().max().unwrap_or(&1),
            carry,
        }
    }

    /// Members `start..start + len` as a critic of their own (parameter views).
    fn narrow_members(&self, start: i64, len: i64) -> Self {
        Self {
            obs_layer: self.obs_layer.narrow_members(start, len),
            action_layer: self.action_layer.narrow_members(start, len),
            norm: self.norm.narrow_members(start, len),
            shared_hidden: self
                .shared_hidden
                .iter()
                .map(|d| d.narrow_members(start, len))
                .collect(),
            heads: self.heads.narrow_members(start, len),
            action: self.action,
            tanh_action: self.tanh_action,
            num_heads: self.num_heads,
            members: self.members.narrowed(len),
            widest: self.widest,
            carry: self.carry,
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

    /// The carried columns of states `obs [.., N, obs_dim]`, repeated for the
    /// `repeats` actions evaluated per state: `[.., repeats N, F]` (the rows of the
    /// first layer's flattened `[.., repeats, N, h1]`); none when nothing is carried.
    fn carried_rows(&self, obs: &Tensor, repeats: i64) -> Option<Tensor> {
        if self.carry == 0 {
            return None;
        }
        let carried = obs.narrow(-1, obs.size()[obs.dim() - 1] - self.carry, self.carry);
        let mut rows = carried.size();
        let axis = rows.len() - 2;
        let mut shape = rows.clone();
        shape.insert(axis, repeats);
        rows[axis] *= repeats;
        Some(carried.unsqueeze(-3).expand(&shape, false).reshape(&rows))
    }

    /// Further shared layers, then the heads, on first-layer features.
    /// `h [R, h1]`, `carried [R, F] -> [R, C]`.
    fn heads_forward(&self, h: &Tensor, carried: Option<&Tensor>) -> Tensor {
        let mut x = h.shallow_clone();
        for layer in &self.shared_hidden {
            x = layer.forward(&append_carried(x, carried));
            elu_(&mut x);
        }
        self.heads.forward(&append_carried(x, carried), carried)
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
        let h = self.first_layer(obs, &self.action_features(actions));
        self.heads_forward(&h, self.carried_rows(obs, 1).as_ref())
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
            let carried = self.carried_rows(obs, rows);
            self.heads_forward(&h.reshape([rows * n, -1]), carried.as_ref())
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
        let carried = self.carried_rows(obs, n);
        self.heads_forward(&h.reshape([n * rows, -1]), carried.as_ref())
            .reshape([n, rows, self.num_heads])
    }

    /// Further shared layers, then the heads.
    /// `h [P, R, h1]`, `carried [P, R, F] -> [P, R, C]`.
    fn heads_forward_members(&self, h: &Tensor, carried: Option<&Tensor>) -> Tensor {
        let mut x = h.shallow_clone();
        for layer in &self.shared_hidden {
            x = layer.forward_members(&append_carried(x, carried));
            elu_(&mut x);
        }
        self.heads
            .forward_members(&append_carried(x, carried), carried)
    }

    /// Q for one action per state, per member.
    /// # Shapes
    /// `obs [P, N, obs_dim]`, `actions [P, N, D] f32 | [P, N] i64 -> [P, N, C]`.
    pub fn forward_members(&self, obs: &Tensor, actions: &Tensor) -> Tensor {
        if !self.members.stacked() {
            return self
                .forward(&obs.squeeze_dim(0), &actions.squeeze_dim(0))
                .unsqueeze(0);
        }
        let mut h = self
            .action_layer
            .forward_members(&self.action_features(actions));
        let _ = h.g_add_(&self.obs_layer.forward_members(obs));
        let carried = self.carried_rows(obs, 1);
        self.heads_forward_members(&self.norm.forward_tanh_members(&h), carried.as_ref())
    }

    /// Whether a pass on `obs` records gradients (a trainable critic outside
    /// `no_grad`, or an input that requires them).
    fn tracks_gradients(&self, obs: &Tensor) -> bool {
        obs.requires_grad() || (&self.obs_layer.weight * 1.0).requires_grad()
    }

    /// Runs `pass` on chunks of members and concatenates the results along the
    /// member axis: all members at once when tracked or off the CPU, else as many as
    /// keep `rows` rows per member under `MEMBER_CHUNK_VALUES` (at least one; one
    /// member alone runs the single-network pass).
    fn by_member_chunks(
        &self,
        rows: i64,
        tracked: bool,
        device: Device,
        pass: impl Fn(&MultiCritic, i64, i64) -> Tensor,
    ) -> Tensor {
        let p = self.members.count();
        let per_member = rows * self.num_heads.max(1) * self.widest;
        if tracked || device != Device::Cpu || p * per_member <= MEMBER_CHUNK_VALUES {
            return pass(self, 0, p);
        }
        let chunk = (MEMBER_CHUNK_VALUES / per_member).max(1);
        let parts: Vec<Tensor> = (0..p)
            .step_by(chunk as usize)
            .map(|start| {
                let len = chunk.min(p - start);
                pass(&self.narrow_members(start, len), start, len)
            })
            .collect();
        Tensor::cat(&parts, 0)
    }

    /// Q for M actions per state, per member.
    /// # Shapes
    /// `obs [P, N, obs_dim]`, `actions [P, M, N, D] -> [P, M, N, C]`.
    pub fn forward_samples_members(&self, obs: &Tensor, actions: &Tensor) -> Tensor {
        let size = actions.size();
        let (m, n) = (size[1], size[2]);
        let tracked = self.tracks_gradients(obs) || actions.requires_grad();
        self.by_member_chunks(m * n, tracked, obs.device(), |critic, start, len| {
            let obs = obs.narrow(0, start, len);
            let actions = actions.narrow(0, start, len);
            if !critic.members.stacked() {
                return critic
                    .forward_samples(&obs.squeeze_dim(0), &actions.squeeze_dim(0))
                    .unsqueeze(0);
            }
            let per_state = critic.obs_layer.forward_members(&obs).unsqueeze(1);
            let features = critic.action_features(&actions).reshape([len, m * n, -1]);
            let mut h = critic
                .action_layer
                .forward_members(&features)
                .reshape([len, m, n, -1]);
            let _ = h.g_add_(&per_state);
            let h = critic
                .norm
                .forward_tanh_members(&h.reshape([len, m * n, -1]));
            let carried = critic.carried_rows(&obs, m);
            critic.heads_forward_members(&h, carried.as_ref()).reshape([
                len,
                m,
                n,
                critic.num_heads,
            ])
        })
    }

    /// Q for every discrete action, per member (panics for continuous critics).
    /// # Shapes
    /// `obs [P, N, obs_dim] -> [P, A, N, C]`.
    pub fn forward_all_actions_members(&self, obs: &Tensor) -> Tensor {
        let ActionKind::Discrete { n: a } = self.action else {
            panic!("forward_all_actions_members needs a discrete action space");
        };
        let n = obs.size()[1];
        let tracked = self.tracks_gradients(obs);
        self.by_member_chunks(a * n, tracked, obs.device(), |critic, start, len| {
            let obs = obs.narrow(0, start, len);
            if !critic.members.stacked() {
                return critic.forward_all_actions(&obs.squeeze_dim(0)).unsqueeze(0);
            }
            // The one-hot rows of all A actions through the action half: W_act^T.
            let eye = Tensor::eye(a, (Kind::Float, obs.device()))
                .unsqueeze(0)
                .expand([len, a, a], false);
            let per_action = critic.action_layer.forward_members(&eye).unsqueeze(2);
            let per_state = critic.obs_layer.forward_members(&obs).unsqueeze(1);
            let h = (per_action + per_state).reshape([len, a * n, -1]);
            let h = critic.norm.forward_tanh_members(&h);
            let carried = critic.carried_rows(&obs, a);
            critic.heads_forward_members(&h, carried.as_ref()).reshape([
                len,
                a,
                n,
                critic.num_heads,
            ])
        })
    }
}

#[cfg(test)]
mod tests;
