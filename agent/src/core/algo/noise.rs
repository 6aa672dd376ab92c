//! Where a learner step's randomness comes from: the standard-normal noise `xi` that
//! turns the target policy's mean and standard deviation into the M sampled actions
//! `a = mu' + sigma' xi` of policy evaluation (C.2) and the E-step (eq. 33).
//!
//! Training draws it from the learner's own stream (`random::Purpose::LearnerNoise`,
//! keyed by `learner.seed`, counter = learner step). A test can instead hand the learner
//! the noise of each step, so that one full step can be replayed by an independent
//! implementation with the very same samples (`tests/golden.rs`).
//!
//! Shape legend: M samples, N states, D action dims.

use crate::core::random::StreamKey;
use std::collections::VecDeque;
use tch::{Device, Kind, Tensor};

/// Given noise that does not fit the step asking for it.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum NoiseError {
    /// Every given tensor has been used.
    #[error("the given noise is used up; the step asked for shape {wanted:?}")]
    Exhausted {
        /// Shape the step asked for.
        wanted: Vec<i64>,
    },
    /// The next given tensor has another shape.
    #[error("the given noise has shape {got:?}; the step asked for {wanted:?}")]
    Shape {
        /// Shape the step asked for.
        wanted: Vec<i64>,
        /// Shape of the given tensor.
        got: Vec<i64>,
    },
}

/// The source of a learner's sampling noise.
#[derive(Debug)]
pub enum NoiseSource {
    /// Draws from this stream at counter = the learner step: one request per step.
    Draw(StreamKey),
    /// These tensors, one per request, in order.
    Given(VecDeque<Tensor>),
}

impl NoiseSource {
    /// Standard-normal noise of `shape` (f32) on `device` for learner step `step`.
    /// # Shapes
    /// `-> shape`, e.g. `[M, N, D]`.
    pub fn standard_normal(
        &mut self,
        shape: &[i64],
        device: Device,
        step: u64,
    ) -> Result<Tensor, NoiseError> {
        match self {
            NoiseSource::Draw(key) => Ok(key.at(step).normal(shape, device)),
            NoiseSource::Given(queue) => {
                let next = queue.pop_front().ok_or_else(|| NoiseError::Exhausted {
                    wanted: shape.to_vec(),
                })?;
                if next.size() != shape {
                    return Err(NoiseError::Shape {
                        wanted: shape.to_vec(),
                        got: next.size(),
                    });
                }
                Ok(next.to_kind(Kind::Float).to_device(device))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::random::Purpose;

    #[test]
    fn given_noise_is_used_in_order_and_checked() {
        let first = Tensor::from_slice(&[1.0f32, 2.0]).reshape([1, 2, 1]);
        let second = Tensor::from_slice(&[3.0f32]).reshape([1, 1, 1]);
        let mut source = NoiseSource::Given([first.copy(), second].into());
        let got = source.standard_normal(&[1, 2, 1], Device::Cpu, 0).unwrap();
        assert!(got.equal(&first));
        assert_eq!(
            source
                .standard_normal(&[1, 2, 1], Device::Cpu, 1)
                .unwrap_err(),
            NoiseError::Shape {
                wanted: vec![1, 2, 1],
                got: vec![1, 1, 1]
            }
        );
        assert!(matches!(
            source.standard_normal(&[1], Device::Cpu, 2),
            Err(NoiseError::Exhausted { .. })
        ));
        let mut drawn = NoiseSource::Draw(StreamKey::new(0, Purpose::LearnerNoise, 0));
        let step_3 = drawn.standard_normal(&[4, 3, 2], Device::Cpu, 3).unwrap();
        assert_eq!(step_3.size(), vec![4, 3, 2]);
        let again = drawn.standard_normal(&[4, 3, 2], Device::Cpu, 3).unwrap();
        assert!(
            step_3.equal(&again),
            "a step's noise depends on the step alone"
        );
    }
}
