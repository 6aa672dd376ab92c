//! One member's slice of a population learner (`state.rs`), with one network's names
//! and shapes: what actors, run folders and tests read per member.
//!
//! Shape legend: P members, K objectives.

use super::state::{Learner, to_vec};
use crate::core::nets::snapshot::named_member_arrays;
use crate::core::nets::{NamedArray, PolicySnapshot};
use tch::Tensor;

impl Learner {
    /// Member `member`'s online policy parameters, as one network's.
    pub fn member_policy_snapshot(&self, member: usize) -> PolicySnapshot {
        PolicySnapshot {
            tensors: named_member_arrays(&self.nets.policy_vs, self.members, member as i64),
        }
    }

    /// Member `member`'s online policy and critic parameters with one network's names
    /// and shapes (`parameters` of a learner of one member), sorted by name.
    pub fn member_parameters(&self, member: usize) -> Vec<NamedArray> {
        let member = member as i64;
        let mut params = named_member_arrays(&self.nets.policy_vs, self.members, member);
        params.extend(named_member_arrays(
            &self.nets.critic_vs,
            self.members,
            member,
        ));
        params
    }

    /// Member `member`'s duals: eta_k, then every trust-region multiplier.
    pub fn member_duals(&self, member: usize) -> (Vec<f32>, Vec<f32>) {
        let pick = |t: &Tensor| to_vec(&self.members.view(t, member as i64, 1));
        (
            pick(&self.duals.temperature()),
            pick(&self.duals.alpha().flatten(-2, -1)),
        )
    }
}
