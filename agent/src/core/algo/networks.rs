//! A learner's networks and their targets (C.1), built in one fixed order so that
//! each parameter draws the same numbers from a seeded generator, for one member or
//! stacked for a population (`load_members` copies each member's single build in).
//!
//! Shape legend: P members, C learned critics.

use super::objectives::{BoundObjectives, LearnerDims};
use crate::core::learner_config::LearnerConfig;
use crate::core::nets::{Members, MultiCritic, Policy, ValueNet};
use crate::core::random::seeded_init;
use tch::{Device, nn};

/// A target network (C.1): same layout as `online`'s network, built by `build` on a new
/// VarStore on the same device, parameters copied, frozen (no gradients).
fn frozen_copy<N>(
    online: &nn::VarStore,
    build: impl FnOnce(&nn::VarStore) -> N,
) -> Result<(nn::VarStore, N), tch::TchError> {
    let mut vs = nn::VarStore::new(online.device());
    let net = build(&vs);
    vs.copy(online)?;
    vs.freeze();
    Ok((vs, net))
}

/// The critics of either family.
#[derive(Debug)]
#[allow(
    clippy::large_enum_variant,
    reason = "one per learner; boxing buys nothing"
)]
pub(crate) enum Critics {
    /// MO-MPO: Q_c(s, a) with a frozen target copy (C.1).
    Q {
        online: MultiCritic,
        target: MultiCritic,
        target_vs: nn::VarStore,
    },
    /// MO-V-MPO: V_c(s), bootstrapped from itself (D.1).
    V { online: ValueNet },
}

/// A learner's networks: the policy, its target copy and the critics, each with the
/// variable store that holds its parameters.
#[derive(Debug)]
pub(crate) struct Networks {
    pub(crate) policy_vs: nn::VarStore,
    pub(crate) policy: Policy,
    pub(crate) target_policy_vs: nn::VarStore,
    pub(crate) target_policy: Policy,
    pub(crate) critic_vs: nn::VarStore,
    pub(crate) critics: Critics,
}

impl Networks {
    /// The online and target stores, in one order for every `Networks`.
    fn stores(&self) -> Vec<&nn::VarStore> {
        let mut stores = vec![&self.policy_vs, &self.target_policy_vs, &self.critic_vs];
        if let Critics::Q { target_vs, .. } = &self.critics {
            stores.push(target_vs);
        }
        stores
    }

    /// Copies `singles[p]`'s parameters into member p of these stacked networks.
    pub(super) fn load_members(&self, singles: &[Networks]) -> Result<(), tch::TchError> {
        for (p, single) in singles.iter().enumerate() {
            for (stacked, one) in self.stores().into_iter().zip(single.stores()) {
                let vars = stacked.variables();
                for (name, value) in one.variables() {
                    let slot = vars.get(&name).ok_or_else(|| {
                        tch::TchError::FileFormat(format!("no stacked variable {name}"))
                    })?;
                    tch::no_grad(|| slot.get(p as i64).f_copy_(&value))?;
                }
            }
        }
        Ok(())
    }
}

/// One member's networks per config, each built as a learner of that config alone
/// builds them (same parameters, bit for bit); for more than one member, stacked.
pub(super) fn build_member_networks(
    cfgs: &[LearnerConfig],
    bounds: &[BoundObjectives],
    dims: &LearnerDims,
    device: Device,
    members: Members,
) -> Result<Networks, tch::TchError> {
    let mut built = cfgs
        .iter()
        .zip(bounds)
        .map(|(c, b)| seeded_init(c.seed, || build_networks(c, dims, b, device, Members::ONE)))
        .collect::<Result<Vec<_>, _>>()?;
    if !members.stacked() {
        return Ok(built.remove(0));
    }
    // Built under the lock so that its (overwritten) draws cannot change another
    // run's initialisation.
    let stacked = seeded_init(cfgs[0].seed, || {
        build_networks(&cfgs[0], dims, &bounds[0], device, members)
    })?;
    stacked.load_members(&built)?;
    Ok(stacked)
}

/// The networks in today's construction order, which fixes what each parameter
/// draws from the seeded generator (see `random::seeded_init`).
pub(super) fn build_networks(
    cfg: &LearnerConfig,
    dims: &LearnerDims,
    bound: &BoundObjectives,
    device: Device,
    members: Members,
) -> Result<Networks, tch::TchError> {
    let net = &cfg.network;
    let heads = bound.critic_names.len() as i64;
    let policy_vs = nn::VarStore::new(device);
    let build_policy =
        |vs: &nn::VarStore| Policy::with_members(&(vs.root() / "policy"), net, dims, members);
    let policy = build_policy(&policy_vs);
    let (target_policy_vs, target_policy) = frozen_copy(&policy_vs, build_policy)?;
    let critic_vs = nn::VarStore::new(device);
    let critics = if cfg.algorithm.on_policy() {
        Critics::V {
            online: ValueNet::with_members(
                &(critic_vs.root() / "critic"),
                net,
                dims.obs_dim,
                heads,
                members,
            ),
        }
    } else {
        let build = |vs: &nn::VarStore| {
            MultiCritic::with_members(
                &(vs.root() / "critic"),
                net,
                dims.obs_dim,
                dims.action,
                heads,
                dims.carried_features(net.critic_preference),
                members,
            )
        };
        let online = build(&critic_vs);
        let (target_vs, target) = frozen_copy(&critic_vs, build)?;
        Critics::Q {
            online,
            target,
            target_vs,
        }
    };
    Ok(Networks {
        policy_vs,
        policy,
        target_policy_vs,
        target_policy,
        critic_vs,
        critics,
    })
}
