//! A training run's configuration: the env, the actor-learner schedule, and the
//! learner (`config::LearnerConfig`). One TOML file, e.g. `configs/mompo/dst.toml`:
//!
//! ```toml
//! seed = 0
//! [env]
//! id = "dst"
//! num_envs = 8
//! [run]
//! total_env_steps = 40000
//! [learner.algorithm]
//! kind = "mo_mpo"
//! [[learner.objectives]]
//! name = "time"
//! epsilon = 0.01
//! ```

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::config::{ConfigError, LearnerConfig};

/// Which environment the actors step, and where.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EnvConfig {
    /// Env id on the server (`dst`, `humanoid-run`, `gym:Pendulum-v1`, ...).
    pub id: String,
    /// Constructor keyword arguments passed to the server.
    #[serde(default)]
    pub kwargs: serde_json::Map<String, serde_json::Value>,
    /// Servers (host:port) the actors connect to, round-robin; empty = start a local
    /// env_server on 127.0.0.1 for the run.
    #[serde(default)]
    pub servers: Vec<String>,
    /// Env instances per actor session (B).
    #[serde(default = "default_num_envs")]
    pub num_envs: usize,
    /// Actor tasks, each with its own session. With one actor a run is reproducible.
    #[serde(default = "default_num_actors")]
    pub num_actors: usize,
    /// Worker processes that step each actor's B instances in parallel with the server
    /// process (0 = none; at most B - 1). Worth it when one instance's step costs more
    /// than a pipe round trip (MuJoCo tasks) and there are cores to spare; results do
    /// not change.
    #[serde(default)]
    pub workers: usize,
}

fn default_num_envs() -> usize {
    8
}

fn default_num_actors() -> usize {
    1
}

/// The actor-learner schedule (appendix C.1).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RunConfig {
    /// Env steps (summed over instances) after which training stops.
    pub total_env_steps: u64,
    /// Off-policy only: learner steps per env step once the replay is warm. Actors
    /// wait for the learner (and the learner for the actors), so results do not depend
    /// on machine speed. On-policy runs take one step per `vmpo.batch_size` unrolls.
    pub learner_steps_per_env_step: f64,
    /// Off-policy only: transitions in the replay before the learner starts.
    pub min_replay_transitions: usize,
    /// Learner steps between policy publications to the actors.
    pub publish_period: u64,
    /// Learner steps between checkpoints (one is also written at exit).
    pub checkpoint_period: u64,
    /// Learner steps between metric records.
    pub log_period: u64,
    /// Episodes of the final evaluation (deterministic policy).
    pub eval_episodes: usize,
    /// Directory under which `runs/<task>__<algo>__<seed>__<time>/` is made.
    pub runs_dir: PathBuf,
}

impl Default for RunConfig {
    fn default() -> Self {
        Self {
            total_env_steps: 100_000,
            learner_steps_per_env_step: 0.125,
            min_replay_transitions: 1_000,
            publish_period: 1,
            checkpoint_period: 1_000,
            log_period: 50,
            eval_episodes: 10,
            runs_dir: PathBuf::from("runs"),
        }
    }
}

/// Everything `agent train` needs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrainConfig {
    /// Seeds the envs (instance i of actor a gets seed + 1000 a + i), the replay
    /// sampler, the actors' action sampling and the networks (`learner.seed` is set
    /// from it).
    #[serde(default)]
    pub seed: u64,
    /// The environment.
    pub env: EnvConfig,
    /// The schedule.
    #[serde(default)]
    pub run: RunConfig,
    /// The learner (Table 2 defaults).
    #[serde(default)]
    pub learner: LearnerConfig,
}

impl TrainConfig {
    /// Read and validate a TOML file.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|e| ConfigError::Invalid {
            field: "config file".into(),
            requirement: "readable".into(),
            got: format!("{}: {e}", path.display()),
        })?;
        let mut cfg: TrainConfig = toml::from_str(&text).map_err(|e| ConfigError::Invalid {
            field: format!("config file {}", path.display()),
            requirement: "valid TOML matching the schema".into(),
            got: e.to_string(),
        })?;
        cfg.learner.seed = cfg.seed;
        cfg.validate()?;
        Ok(cfg)
    }

    /// Check the run and learner fields.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let invalid = |field: &str, requirement: &str, got: String| {
            Err(ConfigError::Invalid { field: field.into(), requirement: requirement.into(), got })
        };
        if self.env.id.is_empty() {
            return invalid("env.id", "a registered env id", "\"\"".into());
        }
        if self.env.num_envs == 0 {
            return invalid("env.num_envs", ">= 1", "0".into());
        }
        if self.env.num_actors == 0 {
            return invalid("env.num_actors", ">= 1", "0".into());
        }
        if self.env.workers >= self.env.num_envs {
            return invalid(
                "env.workers",
                &format!("at most env.num_envs - 1 = {}", self.env.num_envs - 1),
                self.env.workers.to_string(),
            );
        }
        let r = &self.run;
        if !(r.learner_steps_per_env_step.is_finite() && r.learner_steps_per_env_step > 0.0) {
            return invalid("run.learner_steps_per_env_step", "> 0", r.learner_steps_per_env_step.to_string());
        }
        for (field, v) in [
            ("run.publish_period", r.publish_period),
            ("run.checkpoint_period", r.checkpoint_period),
            ("run.log_period", r.log_period),
        ] {
            if v == 0 {
                return invalid(field, ">= 1", "0".into());
            }
        }
        if r.min_replay_transitions == 0 {
            return invalid("run.min_replay_transitions", ">= 1", "0".into());
        }
        self.learner.validate()
    }

    /// Short algorithm name for run directories and tables.
    pub fn algo_name(&self) -> &'static str {
        self.learner.algorithm.short_name()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn minimal_file_gets_defaults_and_the_seed_reaches_the_learner() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("c.toml");
        std::fs::write(
            &path,
            "seed = 5\n[env]\nid = \"dst\"\n[[learner.objectives]]\nname = \"time\"\nepsilon = 0.01\n",
        )
        .unwrap();
        let cfg = TrainConfig::load(&path).unwrap();
        assert_eq!((cfg.env.num_envs, cfg.env.num_actors, cfg.learner.seed), (8, 1, 5));
        assert_eq!(cfg.run, RunConfig::default());
    }

    #[test]
    fn errors_name_the_field_and_quote_the_value() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("c.toml");
        std::fs::write(&path, "[env]\nid = \"dst\"\nnum_envs = 0\n").unwrap();
        let err = TrainConfig::load(&path).unwrap_err().to_string();
        assert_eq!(err, "env.num_envs must be >= 1, got 0");
        std::fs::write(&path, "[env]\nid = \"dst\"\nnum_envs = 4\nworkers = 4\n").unwrap();
        let err = TrainConfig::load(&path).unwrap_err().to_string();
        assert_eq!(err, "env.workers must be at most env.num_envs - 1 = 3, got 4");
        std::fs::write(&path, "[env]\nid = \"dst\"\nnum_env = 3\n").unwrap();
        let err = TrainConfig::load(&path).unwrap_err().to_string();
        assert!(err.contains("num_env"), "{err}");
    }
}
