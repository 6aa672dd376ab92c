//! Saving and restoring the whole learner state in a directory:
//! - `params.safetensors`: online and target policy and critic variables
//!   (`policy/<name>`, `target_policy/<name>`, `critic/<name>`, and `target_critic/<name>`
//!   for Q critics; V-MPO's value critics have no target)
//!   and the raw dual parameters (`duals/temperature`, `duals/alpha`);
//! - `optimizer.safetensors`: Adam moments of the policy, critic and dual optimizers
//!   (`<optimizer>/exp_avg/<name>`, `<optimizer>/exp_avg_sq/<name>`);
//! - `state.json`: format version, step counter, Adam step counts, dual values (for
//!   reading), the config and the dimensions.
//!
//! Writes are atomic at the directory level: everything goes to `DIR.tmp-<pid>`; then
//! an existing `DIR` is renamed to `DIR.old-<pid>`, the new one renamed to `DIR`, and
//! only then is the old one removed. A crash leaves either the old or the new
//! checkpoint complete under one of those names. Every file and directory is synced
//! before the rename that publishes it, so this holds for a crash of the machine too.
//!
//! A run's checkpoint adds its own files to the same directory (`run.rs`: counters,
//! random-stream positions, logs' lengths) and the replay's segments beside it
//! (`replay.rs`).
//!
//! `duals/alpha` is `[2]` for a Gaussian policy with a summed KL constraint, `[2 D]`
//! with a per-dimension one (`algo/dual.rs`), `[1]` for a categorical policy; the
//! stored config rebuilds the learner with the same shape.
//!
//! The online networks' parameters alone also go in and out as named arrays
//! (`Learner::parameters`, `Learner::load_parameters`), e.g. from a reference
//! implementation.

pub mod replay;
pub mod run;

use crate::core::algo::adam::AdamStateError;
use crate::core::algo::state::Critics;
use crate::core::algo::state::to_vec;
use crate::core::algo::{Learner, LearnerDims, LearnerError};
use crate::core::learner_config::LearnerConfig;
use crate::core::nets::NamedArray;
use crate::core::nets::snapshot::{load_named, named_arrays};
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use tch::{Device, Kind, Tensor, nn};

const FORMAT_VERSION: u32 = 1;

/// Errors of saving or loading a checkpoint.
#[derive(Debug, thiserror::Error)]
pub enum CheckpointError {
    /// File system error, with the path involved.
    #[error("checkpoint {path}: {source}")]
    Io {
        /// Path being read or written.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// `state.json` could not be read or written.
    #[error("checkpoint {path}: {source}")]
    Json {
        /// Path of `state.json`.
        path: PathBuf,
        /// The serde error.
        source: serde_json::Error,
    },
    /// A tensor file is missing a tensor or has a wrong shape.
    #[error("checkpoint {path}: {message}")]
    Content {
        /// File concerned.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// libtorch failed reading or writing safetensors.
    #[error("checkpoint: {0}")]
    Torch(#[from] tch::TchError),
    /// The stored config could not rebuild a learner.
    #[error("checkpoint: {0}")]
    Learner(#[from] LearnerError),
    /// Optimizer state did not fit.
    #[error("checkpoint: {0}")]
    Optimizer(#[from] AdamStateError),
    /// No checkpoint to resume from.
    #[error("no checkpoint in {0} (nothing to resume)")]
    NoCheckpoint(PathBuf),
}

/// One more file written into a checkpoint directory with the learner's, under the
/// same atomic rename.
#[derive(Debug, Clone, Copy)]
pub struct ExtraFile<'a> {
    /// File name inside the directory.
    pub name: &'a str,
    /// Its bytes.
    pub contents: &'a [u8],
}

/// Contents of `state.json`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct CheckpointState {
    /// Layout version of the directory.
    pub format_version: u32,
    /// Learner steps done.
    pub step: u64,
    /// Adam step counts: policy, critic, duals.
    pub adam_steps: [i64; 3],
    /// eta_k per objective (informational; the exact values are in params.safetensors).
    pub temperature: Vec<f32>,
    /// alpha values (informational).
    pub alpha: Vec<f32>,
    /// Learner configuration.
    pub config: LearnerConfig,
    /// Dimensions the learner was built for.
    pub dims: LearnerDims,
}

/// Names `path` in an I/O error.
pub(crate) fn io(path: &Path) -> impl FnOnce(std::io::Error) -> CheckpointError + '_ {
    move |source| CheckpointError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// Writes a directory as one step (module docs): `fill` writes its files into a
/// temporary sibling, which is synced and renamed to `dir` once the old `dir` is moved
/// aside, so a crash leaves whole checkpoints only.
fn write_dir_atomically(
    dir: &Path,
    fill: impl FnOnce(&Path) -> Result<(), CheckpointError>,
) -> Result<(), CheckpointError> {
    let name = dir
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "checkpoint".into());
    let parent = dir
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    std::fs::create_dir_all(parent).map_err(io(parent))?;
    let tmp = parent.join(format!("{name}.tmp-{}", std::process::id()));
    if tmp.exists() {
        std::fs::remove_dir_all(&tmp).map_err(io(&tmp))?;
    }
    std::fs::create_dir_all(&tmp).map_err(io(&tmp))?;
    fill(&tmp)?;
    for entry in std::fs::read_dir(&tmp).map_err(io(&tmp))? {
        sync_path(&entry.map_err(io(&tmp))?.path())?;
    }
    sync_path(&tmp)?;
    let old = parent.join(format!("{name}.old-{}", std::process::id()));
    let had_old = dir.exists();
    if had_old {
        std::fs::rename(dir, &old).map_err(io(dir))?;
    }
    std::fs::rename(&tmp, dir).map_err(io(dir))?;
    sync_path(parent)?;
    if had_old {
        std::fs::remove_dir_all(&old).map_err(io(&old))?;
    }
    Ok(())
}

/// Flushes `path` (a file, or a directory's entries) to the disk. A rename is atomic
/// against a crash of the process, but only a synced file and a synced directory
/// survive the machine's crash or power loss (a preempted node) in their renamed state.
pub(crate) fn sync_path(path: &Path) -> Result<(), CheckpointError> {
    std::fs::File::open(path)
        .and_then(|f| f.sync_all())
        .map_err(io(path))
}

fn prefixed(vs: &nn::VarStore, prefix: &str) -> Vec<(String, Tensor)> {
    let mut out: Vec<(String, Tensor)> = vs
        .variables()
        .into_iter()
        .map(|(k, v)| (format!("{prefix}/{k}"), v.detach()))
        .collect();
    out.sort_by(|a, b| a.0.cmp(&b.0));
    out
}

fn load_prefixed(
    vs: &nn::VarStore,
    prefix: &str,
    tensors: &HashMap<String, Tensor>,
    path: &Path,
) -> Result<(), CheckpointError> {
    for (name, mut var) in vs.variables() {
        let key = format!("{prefix}/{name}");
        let src = tensors.get(&key).ok_or_else(|| CheckpointError::Content {
            path: path.to_path_buf(),
            message: format!("missing tensor {key}"),
        })?;
        if src.size() != var.size() {
            let message = format!(
                "tensor {key}: expected shape {:?}, got {:?}",
                var.size(),
                src.size()
            );
            return Err(CheckpointError::Content {
                path: path.to_path_buf(),
                message,
            });
        }
        tch::no_grad(|| var.copy_(src));
    }
    Ok(())
}

fn read_tensors(path: &Path, device: Device) -> Result<HashMap<String, Tensor>, CheckpointError> {
    Ok(Tensor::read_safetensors(path)?
        .into_iter()
        .map(|(k, v)| (k, v.to_device(device)))
        .collect())
}

impl Learner {
    /// The online policy's and critics' parameters, by VarStore name (`policy.*`,
    /// `critic.*`), sorted by name.
    pub fn parameters(&self) -> Vec<NamedArray> {
        let mut params = named_arrays(&self.nets.policy_vs);
        params.extend(named_arrays(&self.nets.critic_vs));
        params
    }

    /// Replaces every online parameter (names and shapes as `parameters` gives them)
    /// and copies them into the target networks, as construction does with its own
    /// initialisation. Optimizer moments and duals are left as they are.
    pub fn load_parameters(&mut self, params: &[NamedArray]) -> Result<(), LearnerError> {
        let (policy, critic): (Vec<NamedArray>, Vec<NamedArray>) = params
            .iter()
            .cloned()
            .partition(|p| p.name.starts_with("policy."));
        load_named(&policy, &self.nets.policy_vs)?;
        load_named(&critic, &self.nets.critic_vs)?;
        self.nets.target_policy_vs.copy(&self.nets.policy_vs)?;
        if let Critics::Q { target_vs, .. } = &mut self.nets.critics {
            target_vs.copy(&self.nets.critic_vs)?;
        }
        Ok(())
    }

    /// Writes the full learner state to `dir` atomically (see module docs).
    pub fn save_checkpoint(&self, dir: &Path) -> Result<(), CheckpointError> {
        self.save_checkpoint_with(dir, &[])
    }

    /// As [`Learner::save_checkpoint`], with `extra` files in the same directory.
    pub fn save_checkpoint_with(
        &self,
        dir: &Path,
        extra: &[ExtraFile<'_>],
    ) -> Result<(), CheckpointError> {
        self.save_member_checkpoint(dir, 0, extra)
    }

    /// Member `member`'s checkpoint: its slice of every network, optimizer moment and
    /// dual, with its own config, in the format of a learner of one member (so
    /// `agent eval` and `--resume` read a population member's run as any other).
    pub fn save_member_checkpoint(
        &self,
        dir: &Path,
        member: usize,
        extra: &[ExtraFile<'_>],
    ) -> Result<(), CheckpointError> {
        write_dir_atomically(dir, |tmp| {
            Tensor::write_safetensors(&self.member_params(member), tmp.join("params.safetensors"))?;
            let moments = self.member_moments(member);
            Tensor::write_safetensors(&moments, tmp.join("optimizer.safetensors"))?;
            let json_path = tmp.join("state.json");
            let text =
                serde_json::to_string_pretty(&self.member_state(member)).map_err(|source| {
                    CheckpointError::Json {
                        path: json_path.clone(),
                        source,
                    }
                })?;
            std::fs::write(&json_path, text).map_err(io(&json_path))?;
            for file in extra {
                let path = tmp.join(file.name);
                std::fs::write(&path, file.contents).map_err(io(&path))?;
            }
            Ok(())
        })
    }

    /// Member `member`'s slice of a `[P, ...]` tensor.
    fn member_view(&self, t: &Tensor, member: usize) -> Tensor {
        self.members.view(t, member as i64, 1)
    }

    /// Member `member`'s networks, targets and duals, by checkpoint name.
    fn member_params(&self, member: usize) -> Vec<(String, Tensor)> {
        let prefixed = |vs: &nn::VarStore, prefix: &str| -> Vec<(String, Tensor)> {
            prefixed(vs, prefix)
                .into_iter()
                .map(|(k, v)| (k, self.member_view(&v, member)))
                .collect()
        };
        let mut params = prefixed(&self.nets.policy_vs, "policy");
        params.extend(prefixed(&self.nets.target_policy_vs, "target_policy"));
        params.extend(prefixed(&self.nets.critic_vs, "critic"));
        if let Critics::Q { target_vs, .. } = &self.nets.critics {
            params.extend(prefixed(target_vs, "target_critic"));
        }
        let duals = &self.duals;
        params.push((
            "duals/temperature".into(),
            self.member_view(&duals.temperature_param.detach(), member),
        ));
        params.push((
            "duals/alpha".into(),
            self.member_view(&duals.alpha_param.detach(), member),
        ));
        params
    }

    /// Member `member`'s Adam moments of every optimizer, by checkpoint name.
    fn member_moments(&self, member: usize) -> Vec<(String, Tensor)> {
        let mut moments = Vec::new();
        for (prefix, opt) in [
            ("policy", &self.policy_opt),
            ("critic", &self.critic_opt),
            ("duals", &self.duals.optimizer),
        ] {
            moments.extend(
                opt.state_tensors()
                    .into_iter()
                    .map(|(k, v)| (format!("{prefix}/{k}"), self.member_view(&v, member))),
            );
        }
        moments
    }

    /// Member `member`'s `state.json`: step counts, duals, config and dimensions.
    fn member_state(&self, member: usize) -> CheckpointState {
        let alpha = self.member_view(&self.duals.alpha(), member);
        CheckpointState {
            format_version: FORMAT_VERSION,
            step: self.step,
            adam_steps: [
                self.policy_opt.step_count(),
                self.critic_opt.step_count(),
                self.duals.optimizer.step_count(),
            ],
            temperature: self.member_duals(member).0,
            alpha: to_vec(&alpha.mean_dim(-1, false, Kind::Float)),
            config: self.member_cfgs[member].clone(),
            dims: self.dims.clone(),
        }
    }

    /// Rebuilds a learner from `dir` on `device` with the stored config and dimensions.
    pub fn load_checkpoint(dir: &Path, device: Device) -> Result<Self, CheckpointError> {
        let json_path = dir.join("state.json");
        let text = std::fs::read_to_string(&json_path).map_err(io(&json_path))?;
        let state: CheckpointState =
            serde_json::from_str(&text).map_err(|source| CheckpointError::Json {
                path: json_path.clone(),
                source,
            })?;
        if state.format_version != FORMAT_VERSION {
            let message = format!(
                "format_version {} is not {FORMAT_VERSION}",
                state.format_version
            );
            return Err(CheckpointError::Content {
                path: json_path,
                message,
            });
        }
        let mut learner = Learner::new(state.config.clone(), state.dims.clone(), device)?;
        let params_path = dir.join("params.safetensors");
        let params = read_tensors(&params_path, device)?;
        load_prefixed(&learner.nets.policy_vs, "policy", &params, &params_path)?;
        load_prefixed(
            &learner.nets.target_policy_vs,
            "target_policy",
            &params,
            &params_path,
        )?;
        load_prefixed(&learner.nets.critic_vs, "critic", &params, &params_path)?;
        if let Critics::Q { target_vs, .. } = &learner.nets.critics {
            load_prefixed(target_vs, "target_critic", &params, &params_path)?;
        }
        for (key, dst) in [
            ("duals/temperature", &mut learner.duals.temperature_param),
            ("duals/alpha", &mut learner.duals.alpha_param),
        ] {
            let src = params
                .get(key)
                .filter(|s| s.size() == dst.size())
                .ok_or_else(|| CheckpointError::Content {
                    path: params_path.clone(),
                    message: format!("missing or mis-shaped tensor {key}"),
                })?;
            tch::no_grad(|| dst.copy_(src));
        }
        let opt_path = dir.join("optimizer.safetensors");
        let moments = read_tensors(&opt_path, device)?;
        let [policy_steps, critic_steps, dual_steps] = state.adam_steps;
        learner
            .policy_opt
            .load_state(&moments, "policy/", policy_steps)?;
        learner
            .critic_opt
            .load_state(&moments, "critic/", critic_steps)?;
        learner
            .duals
            .optimizer
            .load_state(&moments, "duals/", dual_steps)?;
        learner.step = state.step;
        Ok(learner)
    }
}
