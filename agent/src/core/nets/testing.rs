//! Helpers of the networks' unit tests: keyed test inputs, and blinding the weights
//! that read carried preference columns.

use crate::core::random::{Purpose, StreamKey};
use tch::{Device, Tensor, nn};

/// Test inputs from a keyed stream (`at` picks the draw), not libtorch's shared
/// generator.
pub(crate) fn normal(shape: &[i64], at: u64) -> Tensor {
    StreamKey::new(0, Purpose::LearnerActing, 0)
        .at(at)
        .normal(shape, Device::Cpu)
}

/// Zeroes, in every weight of `vs` but `keep`, the entries that read the last `carry`
/// input columns: the end of axis 1, the input axis of a dense `[out, in]` weight and
/// of a head stack's `[C, in, out]`. Weights no wider than `carry` (a critic's action
/// half) are left alone.
pub(crate) fn blind_carried_inputs(vs: &nn::VarStore, keep: &str, carry: i64) {
    tch::no_grad(|| {
        for (name, var) in vs.variables() {
            if name.ends_with("weight") && var.dim() >= 2 && name != keep {
                let inputs = var.size()[1];
                if inputs > carry {
                    let _ = var.narrow(1, inputs - carry, carry).zero_();
                }
            }
        }
    });
}
