//! `agent act`: the deterministic actions a checkpoint's policy takes for observations
//! given in a file, so that another implementation of the policy (such as
//! `env_server.trained_policy` in PyTorch) can be checked against the agent's own.
//!
//! Observations are rows of the flattened observation (`[B, obs_dim]`, Dict leaves in
//! the checkpoint's `dims.obs_leaves` order), as a `.npy` array (any float or int
//! dtype, or one row `[obs_dim]`) or JSON (a list of rows, or one row). Actions are
//! what the actor sends the env: a continuous action is the Gaussian's mean, clipped to
//! [-1, 1] and mapped onto the Box bounds where both are finite (`[B, D]` float32); a
//! discrete one is the most likely index (`[B]` int64; the env adds its space's
//! `start`, which the checkpoint does not store).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use tch::{Kind, Tensor};

use crate::core::nets::{Acting, ActionKind, ActorPolicy, LearnerDims};
use crate::runtime::eval::{CheckpointPolicy, EvalError, load_checkpoint_policy};

/// Errors of `agent act`.
#[derive(Debug, thiserror::Error)]
pub enum ActError {
    /// The checkpoint could not be loaded.
    #[error(transparent)]
    Load(#[from] EvalError),
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// File involved.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// A `.npy` file could not be read or written.
    #[error("{path}: {source}")]
    Npy {
        /// File involved.
        path: PathBuf,
        /// libtorch's error.
        source: tch::TchError,
    },
    /// The observations do not fit the policy, or a file is of an unknown kind.
    #[error("{path}: {field}: expected {expected}, got {got}")]
    BadInput {
        /// File involved.
        path: PathBuf,
        /// What in the file is wrong.
        field: String,
        /// What fits.
        expected: String,
        /// What arrived.
        got: String,
    },
}

/// The deterministic env actions of the checkpoint at `checkpoint` (a run directory or
/// one `checkpoints/step_<n>`) for the observations in `observations`, written to
/// `out` (`.npy` or `.json`); returns the actions as JSON text when `out` is `None`.
/// An ε-conditioned policy acts at `epsilon` (default: its grid's middle point); its
/// observations are the env's, without the preference features, which it appends.
pub fn act_on_file(
    checkpoint: &Path,
    observations: &Path,
    out: Option<&Path>,
    epsilon: Option<&BTreeMap<String, f64>>,
) -> Result<Option<String>, ActError> {
    let mut loaded = load_checkpoint_policy(checkpoint)?;
    if let Some(epsilon) = epsilon {
        loaded = loaded.with_epsilon(epsilon)?;
    }
    let CheckpointPolicy { dims, policy, .. } = loaded;
    let env_obs_dim = dims.obs_dim - dims.preference_features() as i64;
    let obs = read_observations(observations, env_obs_dim)?;
    let actions = env_actions(&policy, &dims, &obs);
    match out {
        Some(path) => {
            write_actions(path, &actions)?;
            Ok(None)
        }
        None => Ok(Some(actions_json(&actions))),
    }
}

/// The actions the actor would send the env for `obs` with the deterministic policy.
/// # Shapes
/// `obs [B, obs_dim] -> [B, D]` float32 (continuous) or `[B]` int64 (discrete).
pub fn env_actions(policy: &ActorPolicy, dims: &LearnerDims, obs: &Tensor) -> Tensor {
    let actions = policy.act(obs, Acting::Deterministic).actions;
    match (&dims.action, &dims.action_bounds) {
        (ActionKind::Continuous { .. }, Some(bounds)) => bounds.to_env(&actions),
        // A checkpoint from before the bounds were stored: executed clipped to [-1, 1].
        (ActionKind::Continuous { .. }, None) => actions.clamp(-1.0, 1.0),
        (ActionKind::Discrete { .. }, _) => actions.to_kind(Kind::Int64),
    }
}

/// Observations `[B, obs_dim]` float32 from a `.npy` or `.json` file (one row `[obs_dim]`
/// is taken as B = 1).
pub fn read_observations(path: &Path, obs_dim: i64) -> Result<Tensor, ActError> {
    let bad = |field: &str, expected: String, got: String| ActError::BadInput {
        path: path.to_path_buf(),
        field: field.into(),
        expected,
        got,
    };
    let obs = match extension(path).as_str() {
        "npy" => Tensor::read_npy(path)
            .map_err(|source| ActError::Npy {
                path: path.to_path_buf(),
                source,
            })?
            .to_kind(Kind::Float),
        "json" => {
            let text = std::fs::read_to_string(path).map_err(|source| ActError::Io {
                path: path.to_path_buf(),
                source,
            })?;
            let rows: serde_json::Value = serde_json::from_str(&text).map_err(|e| {
                bad(
                    "observations",
                    "JSON: a list of rows of numbers".into(),
                    e.to_string(),
                )
            })?;
            json_rows(&rows).map_err(|(field, got)| {
                bad(&field, "a list of rows of numbers, or one row".into(), got)
            })?
        }
        other => {
            return Err(bad(
                "file name",
                "a .npy or .json file".into(),
                format!("{other:?}"),
            ));
        }
    };
    let obs = if obs.dim() == 1 {
        obs.unsqueeze(0)
    } else {
        obs
    };
    let size = obs.size();
    if size.len() != 2 || size[1] != obs_dim {
        return Err(bad(
            "observations",
            format!("shape [B, {obs_dim}] (the env's flattened observation) or [{obs_dim}]"),
            format!("{size:?}"),
        ));
    }
    Ok(obs)
}

/// A JSON list of rows (or one row) as a float32 tensor; on error the field (`row 3`)
/// and what it held.
fn json_rows(value: &serde_json::Value) -> Result<Tensor, (String, String)> {
    let number = |v: &serde_json::Value, field: String| {
        v.as_f64()
            .map(|x| x as f32)
            .ok_or_else(|| (field, v.to_string()))
    };
    let serde_json::Value::Array(items) = value else {
        return Err(("observations".into(), value.to_string()));
    };
    if items.iter().all(|v| !v.is_array()) {
        let row: Vec<f32> = items
            .iter()
            .enumerate()
            .map(|(j, v)| number(v, format!("element {j}")))
            .collect::<Result<_, _>>()?;
        return Ok(Tensor::from_slice(&row));
    }
    let mut flat = Vec::new();
    let mut width = None;
    for (i, row) in items.iter().enumerate() {
        let serde_json::Value::Array(row) = row else {
            return Err((format!("row {i}"), row.to_string()));
        };
        if *width.get_or_insert(row.len()) != row.len() {
            return Err((
                format!("row {i}"),
                format!(
                    "{} numbers where row 0 has {}",
                    row.len(),
                    width.unwrap_or(0)
                ),
            ));
        }
        for (j, v) in row.iter().enumerate() {
            flat.push(number(v, format!("row {i}, element {j}"))?);
        }
    }
    Ok(Tensor::from_slice(&flat).view([items.len() as i64, width.unwrap_or(0) as i64]))
}

/// `actions` as `.npy` or `.json` (by `path`'s extension).
pub fn write_actions(path: &Path, actions: &Tensor) -> Result<(), ActError> {
    match extension(path).as_str() {
        "npy" => actions.write_npy(path).map_err(|source| ActError::Npy {
            path: path.to_path_buf(),
            source,
        }),
        "json" => {
            std::fs::write(path, actions_json(actions) + "\n").map_err(|source| ActError::Io {
                path: path.to_path_buf(),
                source,
            })
        }
        other => Err(ActError::BadInput {
            path: path.to_path_buf(),
            field: "file name".into(),
            expected: "a .npy or .json file".into(),
            got: format!("{other:?}"),
        }),
    }
}

/// `[B, D]` float actions as a JSON list of rows, `[B]` indices as a list of integers.
/// serde_json writes each f32 in the shortest form that reads back as the same f32.
pub fn actions_json(actions: &Tensor) -> String {
    // Serialised from f32 (not through serde_json::Value, which widens to f64 and
    // would print 0.1f32 as 0.10000000149011612).
    let text = if actions.kind() == Kind::Int64 {
        serde_json::to_string(&Vec::<i64>::try_from(&actions.flatten(0, -1)).expect("i64 actions"))
    } else {
        let width = actions.size().get(1).copied().unwrap_or(1).max(1) as usize;
        let flat = Vec::<f32>::try_from(&actions.to_kind(Kind::Float).flatten(0, -1))
            .expect("f32 actions");
        serde_json::to_string(&flat.chunks(width).collect::<Vec<_>>())
    };
    text.expect("numbers serialise")
}

fn extension(path: &Path) -> String {
    path.extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn json_observations_are_rows_or_one_row() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("obs.json");
        std::fs::write(&path, "[[1, 2.5], [-3, 0]]").unwrap();
        let obs = read_observations(&path, 2).unwrap();
        assert_eq!(obs.size(), [2, 2]);
        assert_eq!(
            Vec::<f32>::try_from(&obs.flatten(0, -1)).unwrap(),
            [1.0, 2.5, -3.0, 0.0]
        );
        std::fs::write(&path, "[0.5, 1]").unwrap();
        assert_eq!(read_observations(&path, 2).unwrap().size(), [1, 2]);
    }

    #[test]
    fn observations_that_do_not_fit_are_refused_by_field() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("obs.json");
        let cases = [
            (
                "[[1, 2], [3]]",
                "row 1: expected a list of rows of numbers, or one row, got 1 numbers where row 0 has 2",
            ),
            (
                "[[1, \"a\"]]",
                "row 0, element 1: expected a list of rows of numbers, or one row, got \"a\"",
            ),
            (
                "[[1, 2, 3]]",
                "observations: expected shape [B, 2] (the env's flattened observation) or [2], got [1, 3]",
            ),
            (
                "{\"obs\": 1}",
                "observations: expected a list of rows of numbers, or one row, got {\"obs\":1}",
            ),
        ];
        for (text, message) in cases {
            std::fs::write(&path, text).unwrap();
            let error = read_observations(&path, 2).unwrap_err().to_string();
            assert_eq!(error, format!("{}: {message}", path.display()), "{text}");
        }
        let csv = dir.path().join("obs.csv");
        std::fs::write(&csv, "1,2").unwrap();
        assert_eq!(
            read_observations(&csv, 2).unwrap_err().to_string(),
            format!(
                "{}: file name: expected a .npy or .json file, got \"csv\"",
                csv.display()
            )
        );
    }

    #[test]
    fn npy_observations_of_any_dtype_and_actions_round_trip() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("obs.npy");
        Tensor::from_slice(&[1.0f64, 2.0, 3.0, 4.0, 5.0, 6.0])
            .view([2, 3])
            .write_npy(&path)
            .unwrap();
        let obs = read_observations(&path, 3).unwrap();
        assert_eq!((obs.size(), obs.kind()), (vec![2, 3], Kind::Float));
        let out = dir.path().join("actions.npy");
        write_actions(&out, &obs).unwrap();
        assert!(Tensor::read_npy(&out).unwrap().equal(&obs));
    }

    #[test]
    fn actions_are_json_rows_or_indices() {
        let continuous = Tensor::from_slice(&[0.1f32, -2.0, 1.0, 0.0]).view([2, 2]);
        assert_eq!(actions_json(&continuous), "[[0.1,-2.0],[1.0,0.0]]");
        let discrete = Tensor::from_slice(&[3i64, 0, 1]);
        assert_eq!(actions_json(&discrete), "[3,0,1]");
    }
}
