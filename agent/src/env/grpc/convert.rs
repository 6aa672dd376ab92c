//! Proto <-> plain-Rust conversions for the gRPC client (part of `env::grpc`, the
//! only code that sees proto types). Every field is converted explicitly, so a
//! protocol change breaks the build here rather than being dropped silently.

use mo_env_proto::v1 as pb;

use crate::core::spec::{
    AutoresetMode, BoxSpace, ClosedForm, DType, DiscreteSpace, EnvSpec, ObjectiveSpec, Space,
};
use crate::env::error::EnvError;
use crate::env::{EpisodeSummary, HostTensor, NamedTensor, Observation, StepResult};

pub(super) fn missing(field: &str) -> EnvError {
    EnvError::Protocol {
        field: field.into(),
        expected: "a value".into(),
        got: "nothing".into(),
    }
}

pub(super) fn dtype_from_proto(raw: i32, field: &str) -> Result<DType, EnvError> {
    Ok(match pb::DType::try_from(raw) {
        Ok(pb::DType::DtypeFloat32) => DType::Float32,
        Ok(pb::DType::DtypeFloat64) => DType::Float64,
        Ok(pb::DType::DtypeInt32) => DType::Int32,
        Ok(pb::DType::DtypeInt64) => DType::Int64,
        Ok(pb::DType::DtypeUint8) => DType::Uint8,
        Ok(pb::DType::DtypeBool) => DType::Bool,
        Ok(pb::DType::DtypeUnspecified) | Err(_) => {
            return Err(EnvError::Protocol {
                field: field.into(),
                expected: "a known dtype".into(),
                got: raw.to_string(),
            });
        }
    })
}

pub(super) fn dtype_to_proto(dtype: DType) -> pb::DType {
    match dtype {
        DType::Float32 => pb::DType::DtypeFloat32,
        DType::Float64 => pb::DType::DtypeFloat64,
        DType::Int32 => pb::DType::DtypeInt32,
        DType::Int64 => pb::DType::DtypeInt64,
        DType::Uint8 => pb::DType::DtypeUint8,
        DType::Bool => pb::DType::DtypeBool,
    }
}

pub(super) fn shape_from_proto(shape: &[i64], field: &str) -> Result<Vec<usize>, EnvError> {
    shape
        .iter()
        .map(|&d| {
            usize::try_from(d).map_err(|_| EnvError::Protocol {
                field: field.into(),
                expected: "non-negative dimensions".into(),
                got: format!("{shape:?}"),
            })
        })
        .collect()
}

pub(super) fn tensor_from_proto(t: pb::Tensor, field: &str) -> Result<HostTensor, EnvError> {
    let dtype = dtype_from_proto(t.dtype, field)?;
    let shape = shape_from_proto(&t.shape, field)?;
    let expected = shape.iter().product::<usize>() * dtype.itemsize();
    if t.data.len() != expected {
        return Err(EnvError::Protocol {
            field: field.into(),
            expected: format!("{expected} bytes for {} {shape:?}", dtype.name()),
            got: format!("{} bytes", t.data.len()),
        });
    }
    Ok(HostTensor {
        dtype,
        shape,
        data: t.data.to_vec(),
    })
}

pub(super) fn tensor_to_proto(t: &HostTensor) -> pb::Tensor {
    pb::Tensor {
        dtype: dtype_to_proto(t.dtype) as i32,
        shape: t.shape.iter().map(|&d| d as i64).collect(),
        data: t.data.clone().into(),
    }
}

pub(super) fn named_from_proto(leaves: Vec<pb::NamedTensor>) -> Result<Vec<NamedTensor>, EnvError> {
    leaves
        .into_iter()
        .map(|l| {
            let field = format!("tensor '{}'", l.name);
            let tensor = tensor_from_proto(l.tensor.ok_or_else(|| missing(&field))?, &field)?;
            Ok(NamedTensor {
                name: l.name,
                tensor,
            })
        })
        .collect()
}

pub(super) fn observation_from_proto(
    leaves: Vec<pb::NamedTensor>,
) -> Result<Observation, EnvError> {
    Ok(Observation {
        leaves: named_from_proto(leaves)?,
    })
}

pub(super) fn step_from_proto(
    r: pb::StepResponse,
    num_envs: usize,
    k: usize,
) -> Result<StepResult, EnvError> {
    let reward = tensor_from_proto(
        r.reward.ok_or_else(|| missing("StepResponse.reward"))?,
        "reward",
    )?;
    if reward.dtype != DType::Float32 || reward.shape != [num_envs, k] {
        return Err(EnvError::Protocol {
            field: "StepResponse.reward".into(),
            expected: format!("float32 [{num_envs}, {k}]"),
            got: format!("{} {:?}", reward.dtype.name(), reward.shape),
        });
    }
    for (name, flags) in [("terminated", &r.terminated), ("truncated", &r.truncated)] {
        if flags.len() != num_envs {
            return Err(EnvError::Protocol {
                field: format!("StepResponse.{name}"),
                expected: format!("{num_envs} flags"),
                got: flags.len().to_string(),
            });
        }
    }
    let episodes = r
        .episodes
        .into_iter()
        .map(|e| EpisodeSummary {
            env_index: e.env_index as usize,
            episode_return: e.episode_return,
            discounted_return: e.discounted_return,
            length: e.length as u64,
            terminated: e.terminated,
            truncated: e.truncated,
        })
        .collect();
    Ok(StepResult {
        observation: observation_from_proto(r.observation)?,
        reward: reward.to_f32_vec(),
        terminated: r.terminated,
        truncated: r.truncated,
        info: named_from_proto(r.info)?,
        episodes,
        final_observation: observation_from_proto(r.final_observation)?,
    })
}

pub(super) fn objective_from_proto(o: pb::ObjectiveSpec) -> ObjectiveSpec {
    ObjectiveSpec {
        name: o.name,
        description: o.description,
        min: o.min,
        max: o.max,
        // Servers older than the field send 0: nothing was scaled.
        scale: if o.scale == 0.0 { 1.0 } else { o.scale },
        closed_form: closed_form_from_proto(o.closed_form),
    }
}

fn closed_form_from_proto(raw: i32) -> ClosedForm {
    match pb::ClosedForm::try_from(raw) {
        // Servers older than the field send 0.
        Ok(pb::ClosedForm::Unspecified) => ClosedForm::Undeclared,
        Ok(pb::ClosedForm::None) => ClosedForm::None,
        Ok(pb::ClosedForm::ActionNorm) => ClosedForm::ActionNorm,
        Err(_) => ClosedForm::Unrecognized(raw),
    }
}

pub(super) fn space_from_proto(space: pb::Space, field: &str) -> Result<Space, EnvError> {
    match space.kind {
        Some(pb::space::Kind::Box(b)) => {
            let shape = shape_from_proto(&b.shape, field)?;
            let numel: usize = shape.iter().product();
            let broadcast = |values: Vec<f64>, which: &str| match values.len() {
                1 => Ok(vec![values[0]; numel]),
                n if n == numel => Ok(values),
                n => Err(EnvError::Protocol {
                    field: format!("{field}.{which}"),
                    expected: format!("1 or {numel} values"),
                    got: n.to_string(),
                }),
            };
            Ok(Space::Box(BoxSpace {
                dtype: dtype_from_proto(b.dtype, field)?,
                low: broadcast(b.low, "low")?,
                high: broadcast(b.high, "high")?,
                shape,
            }))
        }
        Some(pb::space::Kind::Discrete(d)) => Ok(Space::Discrete(DiscreteSpace {
            n: d.n,
            start: d.start,
        })),
        Some(pb::space::Kind::Dict(d)) => d
            .entries
            .into_iter()
            .map(|e| {
                let sub = format!("{field}.{}", e.name);
                let space = space_from_proto(e.space.ok_or_else(|| missing(&sub))?, &sub)?;
                Ok((e.name, space))
            })
            .collect::<Result<_, _>>()
            .map(Space::Dict),
        None => Err(missing(field)),
    }
}

pub(super) fn autoreset_to_proto(mode: AutoresetMode) -> pb::AutoresetMode {
    match mode {
        AutoresetMode::SameStep => pb::AutoresetMode::SameStep,
        AutoresetMode::NextStep => pb::AutoresetMode::NextStep,
        AutoresetMode::Disabled => pb::AutoresetMode::Disabled,
    }
}

pub(super) fn autoreset_from_proto(raw: i32) -> AutoresetMode {
    match pb::AutoresetMode::try_from(raw) {
        Ok(pb::AutoresetMode::NextStep) => AutoresetMode::NextStep,
        Ok(pb::AutoresetMode::Disabled) => AutoresetMode::Disabled,
        _ => AutoresetMode::SameStep,
    }
}

pub(super) fn spec_from_proto(s: pb::EnvSpec) -> Result<EnvSpec, EnvError> {
    Ok(EnvSpec {
        env_id: s.env_id,
        num_envs: usize::try_from(s.num_envs).map_err(|_| missing("EnvSpec.num_envs"))?,
        observation_space: space_from_proto(
            s.observation_space
                .ok_or_else(|| missing("EnvSpec.observation_space"))?,
            "observation_space",
        )?,
        action_space: space_from_proto(
            s.action_space
                .ok_or_else(|| missing("EnvSpec.action_space"))?,
            "action_space",
        )?,
        objectives: s.objectives.into_iter().map(objective_from_proto).collect(),
        max_episode_steps: u64::try_from(s.max_episode_steps).ok().filter(|&n| n > 0),
        autoreset_mode: autoreset_from_proto(s.autoreset_mode),
        discount: s.discount,
        info_keys: s.info_keys,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tensor_round_trip_preserves_bytes() {
        let t = HostTensor::from_f32(vec![2, 3], &[1.0, -2.0, 3.5, 0.0, f32::MAX, -0.25]);
        let back = tensor_from_proto(tensor_to_proto(&t), "t").unwrap();
        assert_eq!(back, t);
        assert_eq!(
            back.to_f32_vec(),
            vec![1.0, -2.0, 3.5, 0.0, f32::MAX, -0.25]
        );
    }

    #[test]
    fn tensor_with_wrong_byte_count_is_a_protocol_error() {
        let mut p = tensor_to_proto(&HostTensor::from_i64(vec![2], &[1, 2]));
        p.data = p.data.slice(0..12);
        let err = tensor_from_proto(p, "action").unwrap_err().to_string();
        assert!(err.contains("expected 16 bytes for int64 [2]"), "{err}");
        assert!(err.contains("got 12 bytes"), "{err}");
    }

    #[test]
    fn box_bounds_broadcast_from_one_value() {
        let space = pb::Space {
            kind: Some(pb::space::Kind::Box(pb::BoxSpace {
                dtype: pb::DType::DtypeFloat32 as i32,
                shape: vec![3],
                low: vec![-1.0],
                high: vec![1.0, 2.0, 3.0],
            })),
        };
        let Space::Box(b) = space_from_proto(space, "action_space").unwrap() else {
            panic!("not a box")
        };
        assert_eq!(b.low, vec![-1.0; 3]);
        assert_eq!(b.high, vec![1.0, 2.0, 3.0]);
    }
}
