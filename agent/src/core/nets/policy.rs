//! Policies (appendix A): a diagonal Gaussian for continuous actions and a categorical
//! distribution over logits for discrete actions (A.2).
//!
//! Gaussian parameterisation (documented choice): the head outputs `[mean_raw, std_raw]`;
//! `mean = tanh(mean_raw)` when `tanh_on_action_mean` (Table 2) else `mean_raw`, and
//! `std = softplus(std_raw) + sqrt(min_variance)`, so the variance is at least
//! `min_variance` (Table 2 "minimum variance", "maximum variance unbounded"). With
//! `network.policy_std = "state_independent"` the head outputs `mean_raw` only and
//! `std_raw` is one free parameter per action dimension ([`STD_VARIABLE`], initialised
//! at 0: std 0.69, the head's initial scale).
//!
//! Shape legend: B states, M samples per state, D action dims, A discrete actions.

use super::distribution::{GaussianParams, PolicyOutput};
use super::mlp::{Dense, Members};
use super::torso::Torso;
use super::{ActionKind, LearnerDims};
use crate::core::learner_config::{NetworkConfig, PolicyStd};
use crate::core::random::RandomStream;
use tch::{Kind, Tensor, nn};

/// The name of a state-independent policy's standard-deviation parameter `[D]`
/// (`[P, D]` stacked) in the policy's variable store.
pub const STD_VARIABLE: &str = "std_raw";

/// Diagonal Gaussian policy network.
#[derive(Debug)]
pub struct GaussianPolicy {
    torso: Torso,
    head: Dense,
    /// `std_raw [D]` (`[P, D]`) when the standard deviation is state-independent.
    std_raw: Option<Tensor>,
    action_dim: i64,
    tanh_mean: bool,
    min_std: f64,
}

impl GaussianPolicy {
    /// Parameters under `p` (`torso/..`, `head/..`, and the mocap torso's `encoder/..`,
    /// `latent/..`).
    pub fn new(p: &nn::Path, cfg: &NetworkConfig, dims: &LearnerDims, action_dim: i64) -> Self {
        Self::with_members(p, cfg, dims, action_dim, Members::ONE)
    }

    /// As `new`, for `members` networks.
    pub fn with_members(
        p: &nn::Path,
        cfg: &NetworkConfig,
        dims: &LearnerDims,
        action_dim: i64,
        members: Members,
    ) -> Self {
        let torso = Torso::with_members(p, cfg, dims, members);
        let last = torso.output_dim();
        let std_raw = match cfg.policy_std {
            PolicyStd::StateDependent => None,
            PolicyStd::StateIndependent => Some(p.var(
                STD_VARIABLE,
                &members.shape(&[action_dim]),
                nn::Init::Const(0.0),
            )),
        };
        let outputs = match std_raw {
            None => 2 * action_dim,
            Some(_) => action_dim,
        };
        let head = Dense::with_members(&(p / "head"), last, outputs, last, true, members);
        Self {
            torso,
            head,
            std_raw,
            action_dim,
            tanh_mean: cfg.tanh_on_action_mean,
            min_std: cfg.min_variance.sqrt(),
        }
    }

    /// # Shapes
    /// `obs [B, obs_dim]`, latent `noise [B, L]` (mocap torso; `None` draws it)
    /// `-> mean, std [B, D]`.
    pub fn forward(&self, obs: &Tensor, noise: Option<&Tensor>) -> GaussianParams {
        self.params(self.head.forward(&self.torso.forward(obs, noise)))
    }

    /// # Shapes
    /// `obs [P, B, obs_dim]`, latent `noise [B, L]` (one member's mocap torso; `None`
    /// takes the latent's mean) `-> mean, std [P, B, D]`.
    pub fn forward_members(&self, obs: &Tensor, noise: Option<&Tensor>) -> GaussianParams {
        self.params(
            self.head
                .forward_members(&self.torso.forward_members(obs, noise)),
        )
    }

    /// Whether the standard deviation is one parameter per action dimension.
    pub fn state_independent_std(&self) -> bool {
        self.std_raw.is_some()
    }

    /// Mean and std from the head's output `[.., 2 D]` (`[.., D]` and `std_raw`
    /// when the std is state-independent).
    fn params(&self, out: Tensor) -> GaussianParams {
        let parts = out.split(self.action_dim, -1);
        let mean_raw = &parts[0];
        let std_raw = match &self.std_raw {
            None => parts[1].shallow_clone(),
            // [D] broadcasts over [B, D]; stacked [P, D] over [P, B, D].
            Some(raw) if raw.dim() == 2 => raw.unsqueeze(1).expand_as(mean_raw),
            Some(raw) => raw.expand_as(mean_raw),
        };
        let mean = if self.tanh_mean {
            mean_raw.tanh()
        } else {
            mean_raw.shallow_clone()
        };
        let std = std_raw.softplus() + self.min_std;
        GaussianParams { mean, std }
    }
}

/// Categorical policy network over `A` actions (A.2).
#[derive(Debug)]
pub struct CategoricalPolicy {
    torso: Torso,
    head: Dense,
}

impl CategoricalPolicy {
    /// Parameters under `p` (`torso/..`, `head/..`).
    pub fn new(p: &nn::Path, cfg: &NetworkConfig, dims: &LearnerDims, num_actions: i64) -> Self {
        Self::with_members(p, cfg, dims, num_actions, Members::ONE)
    }

    /// As `new`, for `members` networks.
    pub fn with_members(
        p: &nn::Path,
        cfg: &NetworkConfig,
        dims: &LearnerDims,
        num_actions: i64,
        members: Members,
    ) -> Self {
        let torso = Torso::with_members(p, cfg, dims, members);
        let last = torso.output_dim();
        let head = Dense::with_members(&(p / "head"), last, num_actions, last, true, members);
        Self { torso, head }
    }

    /// # Shapes `obs [P, B, obs_dim]`, latent `noise` as `GaussianPolicy`'s `-> [P, B, A]`.
    pub fn forward_members(&self, obs: &Tensor, noise: Option<&Tensor>) -> Tensor {
        self.head
            .forward_members(&self.torso.forward_members(obs, noise))
    }

    /// Unnormalised log-probabilities. # Shapes `obs [B, obs_dim] -> [B, A]`.
    pub fn forward(&self, obs: &Tensor, noise: Option<&Tensor>) -> Tensor {
        self.head.forward(&self.torso.forward(obs, noise))
    }
}

/// Actions chosen for a batch of states, with the log-probabilities the replay
/// stores as the behaviour policy's (Retrace, C.2).
#[derive(Debug)]
pub struct ActOutput {
    /// `[B, D] f32` (continuous, unclipped) or `[B] i64` (discrete).
    pub actions: Tensor,
    /// `[B] f32`: log b(a|s).
    pub log_probs: Tensor,
}

/// How `Policy::act` chooses actions.
#[derive(Debug)]
pub enum Acting<'a> {
    /// The mean (Gaussian) or most likely action (categorical), latent noise zero.
    Deterministic,
    /// Draws from the policy with numbers from this stream.
    Sample(&'a mut RandomStream),
}

/// A Gaussian or categorical policy network.
#[derive(Debug)]
pub enum Policy {
    /// Continuous actions.
    Gaussian(GaussianPolicy),
    /// Discrete actions.
    Categorical(CategoricalPolicy),
}

impl Policy {
    /// Builds the policy for `dims.action` under `p`.
    pub fn new(p: &nn::Path, cfg: &NetworkConfig, dims: &LearnerDims) -> Self {
        Self::with_members(p, cfg, dims, Members::ONE)
    }

    /// As `new`, for `members` networks.
    pub fn with_members(
        p: &nn::Path,
        cfg: &NetworkConfig,
        dims: &LearnerDims,
        members: Members,
    ) -> Self {
        match dims.action {
            ActionKind::Continuous { dim } => {
                Policy::Gaussian(GaussianPolicy::with_members(p, cfg, dims, dim, members))
            }
            ActionKind::Discrete { n } => {
                Policy::Categorical(CategoricalPolicy::with_members(p, cfg, dims, n, members))
            }
        }
    }

    /// Every member's distribution on its own states; a latent torso (one member
    /// only) reads the latent `noise [B, L]`, or its mean when `None`.
    /// # Shapes
    /// `obs [P, B, obs_dim] -> [P, B, D]` (mean, std) or `[P, B, A]` (logits).
    pub fn forward_members(&self, obs: &Tensor, noise: Option<&Tensor>) -> PolicyOutput {
        match self {
            Policy::Gaussian(g) => PolicyOutput::Gaussian(g.forward_members(obs, noise)),
            Policy::Categorical(c) => PolicyOutput::Categorical(c.forward_members(obs, noise)),
        }
    }

    /// # Shapes
    /// `obs [B, obs_dim]`; a latent torso draws fresh noise.
    pub fn forward(&self, obs: &Tensor) -> PolicyOutput {
        self.forward_with_noise(obs, None)
    }

    /// As `forward`, with the latent noise `[B, L]` of a latent torso given.
    pub fn forward_with_noise(&self, obs: &Tensor, noise: Option<&Tensor>) -> PolicyOutput {
        match self {
            Policy::Gaussian(g) => PolicyOutput::Gaussian(g.forward(obs, noise)),
            Policy::Categorical(c) => PolicyOutput::Categorical(c.forward(obs, noise)),
        }
    }

    /// Whether a Gaussian policy's standard deviation is one parameter per action
    /// dimension ([`STD_VARIABLE`]); false for state-dependent ones and categoricals.
    pub fn state_independent_std(&self) -> bool {
        matches!(self, Policy::Gaussian(g) if g.state_independent_std())
    }

    /// The latent width of a latent torso, `None` for a plain one.
    pub fn latent_dim(&self) -> Option<i64> {
        match self {
            Policy::Gaussian(g) => g.torso.latent_dim(),
            Policy::Categorical(c) => c.torso.latent_dim(),
        }
    }

    /// Latent noise `[rows, L]` from `stream`, `None` when the torso has no latent.
    pub fn latent_noise(&self, rows: i64, stream: &mut RandomStream) -> Option<Tensor> {
        let device = match self {
            Policy::Gaussian(g) => g.head.weight.device(),
            Policy::Categorical(c) => c.head.weight.device(),
        };
        self.latent_dim().map(|l| stream.normal(&[rows, l], device))
    }

    /// Samples actions from `stream` (or takes the mean / most likely action).
    /// Runs without gradient tracking.
    ///
    /// A categorical sample is the inverse CDF of one uniform per state: the first
    /// action whose cumulative probability exceeds it.
    pub fn act(&self, obs: &Tensor, acting: Acting<'_>) -> ActOutput {
        tch::no_grad(|| {
            let rows = obs.size()[0];
            let device = obs.device();
            // The deterministic policy uses the latent's mean (zero noise).
            let (noise, stream) = match acting {
                Acting::Deterministic => (
                    self.latent_dim()
                        .map(|l| Tensor::zeros([rows, l], (Kind::Float, device))),
                    None,
                ),
                Acting::Sample(stream) => (self.latent_noise(rows, stream), Some(stream)),
            };
            let out = self.forward_with_noise(obs, noise.as_ref());
            let actions = match (&out, stream) {
                (PolicyOutput::Gaussian(g), None) => g.mean.shallow_clone(),
                (PolicyOutput::Gaussian(g), Some(stream)) => {
                    g.sample_from(&stream.normal(&g.mean.size(), device))
                }
                (PolicyOutput::Categorical(logits), None) => logits.argmax(-1, false),
                (PolicyOutput::Categorical(logits), Some(stream)) => {
                    let cdf = logits.softmax(-1, Kind::Float).cumsum(-1, Kind::Float);
                    let u = stream.uniform(&[rows, 1], device);
                    // Rounding can leave the last cumulative probability below u.
                    cdf.lt_tensor(&u)
                        .sum_dim_intlist(-1, false, Kind::Int64)
                        .clamp_max(cdf.size()[1] - 1)
                }
            };
            let log_probs = out.log_prob(&actions);
            ActOutput { actions, log_probs }
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::random::{Purpose, StreamKey};
    use tch::Device;

    fn dims(obs_dim: i64, action: ActionKind) -> LearnerDims {
        LearnerDims {
            action_bounds: None,
            obs_dim,
            action,
            reward_names: vec!["r".into()],
            obs_leaves: Vec::new(),
        }
    }

    #[test]
    fn std_respects_min_variance_and_tanh_mean() {
        let vs = nn::VarStore::new(Device::Cpu);
        let cfg = NetworkConfig {
            min_variance: 1e-4,
            ..NetworkConfig::default()
        };
        let policy = GaussianPolicy::new(
            &vs.root(),
            &cfg,
            &dims(3, ActionKind::Continuous { dim: 2 }),
            2,
        );
        let obs = Tensor::randn([64, 3], (Kind::Float, Device::Cpu)) * 1e3;
        let out = policy.forward(&obs, None);
        assert!(out.std.min().double_value(&[]) >= 1e-2);
        assert!(out.mean.abs().max().double_value(&[]) <= 1.0);
    }

    #[test]
    fn a_state_independent_std_is_one_learned_value_per_dimension() {
        let cfg = NetworkConfig {
            policy_std: PolicyStd::StateIndependent,
            ..NetworkConfig::default()
        };
        let continuous = dims(3, ActionKind::Continuous { dim: 2 });
        let vs = nn::VarStore::new(Device::Cpu);
        let policy = GaussianPolicy::new(&vs.root(), &cfg, &continuous, 2);
        assert_eq!(vs.variables()[STD_VARIABLE].size(), vec![2]);
        assert_eq!(
            vs.variables()["head.weight"].size()[0],
            2,
            "mean outputs only"
        );
        let mut stream = StreamKey::new(0, Purpose::Acting, 0).at(0);
        let out = policy.forward(&stream.normal(&[5, 3], Device::Cpu), None);
        assert_eq!(out.std.size(), vec![5, 2]);
        // softplus(0) = ln 2 at every state and dimension.
        let gap = (&out.std - 2f64.ln()).abs().max().double_value(&[]);
        assert!(gap < 1e-5, "{:?}", out.std);
        // Stacked members: [P, D], broadcast over each member's states.
        let vs = nn::VarStore::new(Device::Cpu);
        let members = Members::new(3).unwrap();
        let stacked = GaussianPolicy::with_members(&vs.root(), &cfg, &continuous, 2, members);
        assert_eq!(vs.variables()[STD_VARIABLE].size(), vec![3, 2]);
        let obs = stream.normal(&[3, 4, 3], Device::Cpu);
        let out = stacked.forward_members(&obs, None);
        assert_eq!(out.std.size(), vec![3, 4, 2]);
        // The gradient of a loss on std reaches std_raw alone among the parameters.
        out.std.sum(Kind::Float).backward();
        let head = vs.variables()["head.weight"].grad();
        assert!(!head.defined() || head.abs().max().double_value(&[]) == 0.0);
        assert!(
            vs.variables()[STD_VARIABLE]
                .grad()
                .abs()
                .min()
                .double_value(&[])
                > 0.0
        );
    }

    #[test]
    fn categorical_act_returns_indices_and_log_probs() {
        let vs = nn::VarStore::new(Device::Cpu);
        let policy = Policy::new(
            &vs.root(),
            &NetworkConfig::default(),
            &dims(3, ActionKind::Discrete { n: 4 }),
        );
        let mut stream = StreamKey::new(0, Purpose::Acting, 0).at(0);
        let obs = Tensor::zeros([6, 3], (Kind::Float, Device::Cpu));
        let act = policy.act(&obs, Acting::Sample(&mut stream));
        assert_eq!(act.actions.size(), vec![6]);
        assert_eq!(act.actions.kind(), Kind::Int64);
        let max = act.log_probs.max().double_value(&[]);
        assert!(max <= 0.0 && max > -20.0);
    }

    #[test]
    fn categorical_samples_follow_the_probabilities_and_the_stream() {
        let vs = nn::VarStore::new(Device::Cpu);
        let policy = Policy::new(
            &vs.root(),
            &NetworkConfig::default(),
            &dims(3, ActionKind::Discrete { n: 4 }),
        );
        // One state repeated: every row has the same probabilities p.
        let obs = Tensor::ones([20_000, 3], (Kind::Float, Device::Cpu));
        let PolicyOutput::Categorical(logits) = policy.forward(&obs.narrow(0, 0, 1)) else {
            unreachable!("a discrete action space gives a categorical policy")
        };
        let p = Vec::<f32>::try_from(logits.softmax(-1, Kind::Float).flatten(0, -1)).unwrap();
        let key = StreamKey::new(5, Purpose::Acting, 0);
        let actions = policy.act(&obs, Acting::Sample(&mut key.at(0))).actions;
        for (a, &p_a) in p.iter().enumerate() {
            let freq = actions
                .eq(a as i64)
                .to_kind(Kind::Double)
                .mean(Kind::Double);
            // Binomial standard error sqrt(p(1-p)/n) <= 0.0036 at n = 20,000.
            assert!(
                (freq.double_value(&[]) - p_a as f64).abs() < 0.02,
                "action {a}: frequency {freq} against probability {p_a}"
            );
        }
        let again = policy.act(&obs, Acting::Sample(&mut key.at(0))).actions;
        assert!(
            actions.equal(&again),
            "the same stream gives the same actions"
        );
    }
}
