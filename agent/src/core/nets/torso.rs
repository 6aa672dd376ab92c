//! Policy torsos: the plain LayerNorm MLP (Table 2) and the humanoid mocap encoder of
//! appendix A.3. An ε-conditioned plain torso may carry its preference features to
//! every layer (`network.policy_preference`).
//!
//! Mocap: an encoder MLP (`encoder_layers`, 1024x2) reads the whole observation
//! (reference and proprioception), linear layers give the mean and log standard
//! deviation of a latent `z` (`latent_dim`), and the `policy_layers` MLP (1024x2) reads
//! `[z, proprioception]`. `z = mean + std * xi` with `xi ~ N(0, I)` drawn by the caller
//! or here, so that the learner can evaluate the online and target policies with the
//! same `xi` (their KL is then the KL of the action distributions given one latent
//! noise). The log standard deviation is clamped to [-5, 2] so that the latent noise
//! can neither vanish numerically nor swamp the encoder's signal.
//!
//! Shape legend: B states, O observation size, P proprioceptive size, L latent size.

use super::LearnerDims;
use super::mlp::{Dense, LayerNormMlp, Members};
use crate::core::learner_config::{Architecture, NetworkConfig};
use tch::{Kind, Tensor, nn};

const LOG_STD_MIN: f64 = -5.0;
const LOG_STD_MAX: f64 = 2.0;

/// A.3's reference encoder with a stochastic latent, followed by the policy MLP.
#[derive(Debug)]
pub struct MocapTorso {
    encoder: LayerNormMlp,
    latent: Dense,
    proprio_idx: Tensor,
    policy: LayerNormMlp,
    latent_dim: i64,
}

impl MocapTorso {
    /// # Shapes
    /// `obs [B, O]`, `noise [B, L]` (zeros give the latent mean) `-> [B, policy_layers.last()]`.
    pub fn forward(&self, obs: &Tensor, noise: &Tensor) -> Tensor {
        let stats = self.latent.forward(&self.encoder.forward(obs));
        let parts = stats.split(self.latent_dim, -1);
        let std = parts[1].clamp(LOG_STD_MIN, LOG_STD_MAX).exp();
        let z = &parts[0] + std * noise;
        let proprio = obs.index_select(-1, &self.proprio_idx);
        self.policy.forward(&Tensor::cat(&[z, proprio], -1))
    }
}

/// The part of a policy before its distribution head.
#[derive(Debug)]
pub enum Torso {
    /// `policy_layers` on the observation.
    Mlp(LayerNormMlp),
    /// A.3's mocap encoder, latent and policy MLP.
    Mocap(Box<MocapTorso>),
}

impl Torso {
    /// Builds the configured torso under `p`.
    ///
    /// Panics for a mocap architecture on an observation without both reference and
    /// proprioceptive leaves; `algo::objectives::bind_config` rejects such configs first.
    pub fn new(p: &nn::Path, cfg: &NetworkConfig, dims: &LearnerDims) -> Self {
        Self::with_members(p, cfg, dims, Members::ONE)
    }

    /// As `new`, for `members` networks. Panics for a stacked mocap torso: populations
    /// have plain torsos (`algo::population::check_population` refuses them first).
    pub fn with_members(
        p: &nn::Path,
        cfg: &NetworkConfig,
        dims: &LearnerDims,
        members: Members,
    ) -> Self {
        match &cfg.architecture {
            Architecture::Mlp => Torso::Mlp(LayerNormMlp::carrying(
                &(p / "torso"),
                dims.obs_dim,
                &cfg.policy_layers,
                dims.carried_features(cfg.policy_preference),
                members,
            )),
            Architecture::Mocap {
                encoder_layers,
                latent_dim,
                reference_match,
            } => {
                assert!(!members.stacked(), "a mocap torso has one member");
                let split = dims.split_observation(reference_match);
                assert!(
                    !split.matching.is_empty() && !split.rest.is_empty(),
                    "mocap architecture needs reference and proprioceptive observation leaves"
                );
                let encoder = LayerNormMlp::new(&(p / "encoder"), dims.obs_dim, encoder_layers);
                let width = encoder.output_dim();
                let latent = Dense::new(&(p / "latent"), width, 2 * latent_dim, width, true);
                let proprio = split.rest.len() as i64;
                let policy =
                    LayerNormMlp::new(&(p / "torso"), latent_dim + proprio, &cfg.policy_layers);
                Torso::Mocap(Box::new(MocapTorso {
                    encoder,
                    latent,
                    proprio_idx: Tensor::from_slice(&split.rest).to_device(p.device()),
                    policy,
                    latent_dim: *latent_dim,
                }))
            }
        }
    }

    /// Width of the features.
    pub fn output_dim(&self) -> i64 {
        match self {
            Torso::Mlp(m) => m.output_dim(),
            Torso::Mocap(m) => m.policy.output_dim(),
        }
    }

    /// The latent width L, or `None` for torsos without a latent.
    pub fn latent_dim(&self) -> Option<i64> {
        match self {
            Torso::Mlp(_) => None,
            Torso::Mocap(m) => Some(m.latent_dim),
        }
    }

    /// # Shapes
    /// `obs [B, O]`, `noise [B, L]`, or `None` for the latent's mean `-> [B, F]`.
    ///
    /// A sampled latent is always the caller's (from its own random stream), so that
    /// no forward pass draws numbers of its own.
    pub fn forward(&self, obs: &Tensor, noise: Option<&Tensor>) -> Tensor {
        match self {
            Torso::Mlp(m) => m.forward(obs),
            Torso::Mocap(m) => match noise {
                Some(xi) => m.forward(obs, xi),
                None => m.forward(
                    obs,
                    &Tensor::zeros([obs.size()[0], m.latent_dim], (Kind::Float, obs.device())),
                ),
            },
        }
    }
}

impl Torso {
    /// # Shapes
    /// `obs [P, B, O] -> [P, B, F]` (plain torsos; one member's mocap torso, with the
    /// latent `noise [B, L]` as `forward`).
    pub fn forward_members(&self, obs: &Tensor, noise: Option<&Tensor>) -> Tensor {
        match self {
            Torso::Mlp(m) => m.forward_members(obs),
            Torso::Mocap(_) => self.forward(&obs.squeeze_dim(0), noise).unsqueeze(0),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::nets::{ActionKind, ObsLeaf};
    use crate::core::random::{Purpose, StreamKey};
    use tch::Device;

    #[test]
    fn mocap_torso_reads_proprioception_after_the_latent() {
        let dims = LearnerDims {
            action_bounds: None,
            obs_dim: 5,
            action: ActionKind::Continuous { dim: 2 },
            reward_names: vec!["a".into()],
            obs_leaves: vec![
                ObsLeaf {
                    name: "walker/joints".into(),
                    dim: 2,
                },
                ObsLeaf {
                    name: "walker/reference_rel".into(),
                    dim: 3,
                },
            ],
        };
        let cfg = NetworkConfig {
            policy_layers: vec![8],
            architecture: Architecture::Mocap {
                encoder_layers: vec![6],
                latent_dim: 4,
                reference_match: "reference".into(),
            },
            ..NetworkConfig::default()
        };
        let vs = nn::VarStore::new(Device::Cpu);
        let torso = Torso::new(&vs.root(), &cfg, &dims);
        let mut stream = StreamKey::new(0, Purpose::LatentNoise, 0).at(0);
        let obs = stream.normal(&[3, 5], Device::Cpu);
        assert_eq!(torso.latent_dim(), Some(4));
        let xi = stream.normal(&[3, 4], Device::Cpu);
        assert_eq!(xi.size(), vec![3, 4]);
        let a = torso.forward(&obs, Some(&xi));
        assert_eq!(a.size(), vec![3, 8]);
        assert!(
            a.allclose(&torso.forward(&obs, Some(&xi)), 1e-6, 1e-6, false),
            "same noise, same output"
        );
        assert!(
            !a.allclose(&torso.forward(&obs, Some(&(xi + 1.0))), 1e-4, 1e-4, false),
            "the latent matters"
        );
        assert_eq!(
            vs.variables().len(),
            2 + 2 + 2 + 2 + 2,
            "encoder (linear+norm), latent, policy (linear+norm)"
        );
    }
}
