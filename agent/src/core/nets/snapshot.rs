//! Publishing the learner's policy to actors: a plain, engine-free copy of the policy
//! parameters (`PolicySnapshot`) and a CPU-side `ActorPolicy` that loads it. The same
//! named arrays carry any network's parameters in and out (`named_arrays`, `load_named`).

use super::LearnerDims;
use super::mlp::Members;
use super::policy::{ActOutput, Acting, Policy};
use crate::core::learner_config::NetworkConfig;
use crate::core::random::seeded_init;
use tch::{Device, Kind, Tensor, nn};

/// One parameter tensor as plain data.
#[derive(Debug, Clone, PartialEq)]
pub struct NamedArray {
    /// VarStore name, e.g. `policy.torso.linear_0.weight`.
    pub name: String,
    /// Tensor shape.
    pub shape: Vec<i64>,
    /// Row-major f32 values.
    pub data: Vec<f32>,
}

/// All policy parameters, sorted by name.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct PolicySnapshot {
    /// Parameters sorted by name.
    pub tensors: Vec<NamedArray>,
}

/// Parameters that do not fit the receiving network.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SnapshotError {
    /// Parameter names differ.
    #[error("parameter names differ: missing {missing:?}, unexpected {unexpected:?}")]
    Names {
        /// Expected by the receiver but absent from the snapshot.
        missing: Vec<String>,
        /// In the snapshot but unknown to the receiver.
        unexpected: Vec<String>,
    },
    /// A parameter has the wrong shape or data length.
    #[error("parameter {name}: expected shape {expected:?}, got {got:?} with {len} values")]
    Shape {
        /// Parameter name.
        name: String,
        /// Receiver's shape.
        expected: Vec<i64>,
        /// Snapshot's shape.
        got: Vec<i64>,
        /// Snapshot's data length.
        len: usize,
    },
}

impl PolicySnapshot {
    /// Copies every variable of `vs` to host memory.
    pub fn from_var_store(vs: &nn::VarStore) -> Self {
        Self {
            tensors: named_arrays(vs),
        }
    }

    /// Overwrites the variables of `vs` (same names and shapes required).
    pub fn load_into(&self, vs: &nn::VarStore) -> Result<(), SnapshotError> {
        load_named(&self.tensors, vs)
    }
}

/// Every variable of `vs` as host data, sorted by name.
pub fn named_arrays(vs: &nn::VarStore) -> Vec<NamedArray> {
    named_member_arrays(vs, Members::ONE, 0)
}

/// Member `member`'s slice of every variable of `vs` (a layer store of `members`
/// members), with one network's names and shapes, sorted by name.
pub fn named_member_arrays(vs: &nn::VarStore, members: Members, member: i64) -> Vec<NamedArray> {
    let mut tensors: Vec<NamedArray> = vs
        .variables()
        .into_iter()
        .map(|(name, t)| {
            let t = members
                .view(&t, member, 1)
                .detach()
                .to_device(Device::Cpu)
                .to_kind(Kind::Float)
                .contiguous();
            let data = Vec::<f32>::try_from(&t.flatten(0, -1)).expect("f32 tensor converts");
            NamedArray {
                name,
                shape: t.size(),
                data,
            }
        })
        .collect();
    tensors.sort_by(|a, b| a.name.cmp(&b.name));
    tensors
}

/// Overwrites the variables of `vs` with `tensors`: exactly the same names, and the
/// same shapes.
pub fn load_named(tensors: &[NamedArray], vs: &nn::VarStore) -> Result<(), SnapshotError> {
    let vars = vs.variables();
    let missing: Vec<String> = vars
        .keys()
        .filter(|k| !tensors.iter().any(|t| &t.name == *k))
        .cloned()
        .collect();
    let unexpected: Vec<String> = tensors
        .iter()
        .filter(|t| !vars.contains_key(&t.name))
        .map(|t| t.name.clone())
        .collect();
    if !missing.is_empty() || !unexpected.is_empty() {
        return Err(SnapshotError::Names {
            missing,
            unexpected,
        });
    }
    for t in tensors {
        let mut var = vars[&t.name].shallow_clone();
        let numel: i64 = t.shape.iter().product();
        if var.size() != t.shape || numel as usize != t.data.len() {
            return Err(SnapshotError::Shape {
                name: t.name.clone(),
                expected: var.size(),
                got: t.shape.clone(),
                len: t.data.len(),
            });
        }
        let src = Tensor::from_slice(&t.data)
            .reshape(t.shape.as_slice())
            .to_device(var.device());
        tch::no_grad(|| var.copy_(&src));
    }
    Ok(())
}

/// A policy copy for actors (no gradients), fed by `PolicySnapshot`s.
#[derive(Debug)]
pub struct ActorPolicy {
    vs: nn::VarStore,
    policy: Policy,
    /// `[F]` preference features appended to every observation `act` is given (an
    /// ε-conditioned policy evaluated at one preference); `None`: observations are
    /// passed as they are.
    preference: Option<Tensor>,
}

impl ActorPolicy {
    /// A policy with the learner's layout (`policy/..` names) on `device`.
    ///
    /// Its initial weights are placeholders until `load`; they are drawn under
    /// `seeded_init` only so that building one never moves another run's numbers.
    pub fn new(cfg: &NetworkConfig, dims: &LearnerDims, device: Device) -> Self {
        seeded_init(0, || {
            let vs = nn::VarStore::new(device);
            let policy = Policy::new(&(vs.root() / "policy"), cfg, dims);
            Self {
                vs,
                policy,
                preference: None,
            }
        })
    }

    /// Replaces the parameters.
    pub fn load(&mut self, snapshot: &PolicySnapshot) -> Result<(), SnapshotError> {
        snapshot.load_into(&self.vs)
    }

    /// The same policy acting at one preference: `features` (`PreferenceGrid::
    /// features_of`) are appended to every observation row `act` is given.
    pub fn at_preference(mut self, features: &[f32]) -> Self {
        self.preference = Some(Tensor::from_slice(features).to_device(self.vs.device()));
        self
    }

    /// Samples (or takes the mode of) actions. # Shapes `obs [B, obs_dim]` (without the
    /// preference features when `at_preference` set them).
    pub fn act(&self, obs: &Tensor, acting: Acting<'_>) -> ActOutput {
        let obs = obs.to_device(self.vs.device());
        match &self.preference {
            None => self.policy.act(&obs, acting),
            Some(features) => {
                let rows = features.unsqueeze(0).expand([obs.size()[0], -1], false);
                self.policy.act(&Tensor::cat(&[obs, rows], 1), acting)
            }
        }
    }
}
