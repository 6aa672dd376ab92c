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

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::core::learner_config::{ConfigError, LearnerConfig};
use crate::env::connection::ConnectionConfig;
use crate::env::deadline::DeadlineConfig;
use crate::env::discovery::{DiscoveryError, FORMS, ServerSource};
use crate::report::front::FrontConfig;

mod extends;
mod overrides;

pub use overrides::RESUMABLE_FIELDS;
use overrides::apply_override;

/// Which environment the actors step, and where.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EnvConfig {
    /// Env id on the server (`dst`, `humanoid-run`, `gym:Pendulum-v1`, ...).
    pub id: String,
    /// Constructor keyword arguments passed to the server.
    #[serde(default)]
    pub kwargs: serde_json::Map<String, serde_json::Value>,
    /// Servers the actors connect to: `host:port`, `http://…`, `https://…`,
    /// `dns:NAME:PORT` (every A/AAAA record of NAME; `dns://NAMESERVER_IP[:PORT]/NAME:PORT`
    /// asks that name server) or `file:PATH` (one address per line, read again when a
    /// server is lost). Each actor is pinned to one address, spread evenly, and moves to
    /// another when its server stays unreachable. Empty = start a local env_server on
    /// 127.0.0.1 for the run.
    #[serde(default)]
    pub servers: Vec<String>,
    /// TLS and bearer-token files for `servers` (`[env.connection]`); they apply to
    /// every server, and need `servers` (a local server is plain loopback).
    #[serde(default, skip_serializing_if = "ConnectionConfig::is_empty")]
    pub connection: ConnectionConfig,
    /// How long each call to a server may wait for its answer, and when a server that
    /// keeps missing deadlines counts as lost (`[env.deadlines]`; docs/reliability.md).
    #[serde(default)]
    pub deadlines: DeadlineConfig,
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
    /// Learner steps between extra policy publications. The learner always publishes
    /// when it has taken every step the env steps allow, the only moment an actor
    /// loads a policy; these add publications in between (a periodic video takes the
    /// latest). 1 publishes after every step, the earlier default.
    pub publish_period: u64,
    /// Learner steps between checkpoints (one is also written at exit).
    pub checkpoint_period: u64,
    /// Off-policy: checkpoints hold the replay's contents (appended as segments under
    /// `<run>/replay/`), so a resume samples from the replay the run had. `false`
    /// keeps checkpoints small; a resume then refills `min_replay_transitions` and
    /// goes on at the ratio from there (no catch-up burst). On-policy: the queued
    /// unrolls (at most about a batch) are kept or, with `false`, dropped.
    pub checkpoint_replay: bool,
    /// Learner steps between metric records.
    pub log_period: u64,
    /// Episodes of the final evaluation (deterministic policy), and of each periodic one.
    pub eval_episodes: usize,
    /// Env steps between evaluations of the deterministic policy while training, as
    /// Stable-Baselines3's `EvalCallback` (`eval_freq`) does: each runs
    /// `eval_episodes` episodes on a session of its own, seeded as the final
    /// evaluation is, with the policy the actors hold when the env steps reach the
    /// multiple, and writes `eval.csv`, TensorBoard scalars and `eval.png`; an
    /// ε-conditioned run evaluates every grid point and logs its front's hypervolume.
    /// Evaluations change no training step (the run's episodes and learner logs stay
    /// the same). 0 (default): none.
    pub eval_period: u64,
    /// Directory under which `runs/<task>__<algo>__<seed>__<time>/` is made.
    pub runs_dir: PathBuf,
    /// Returns that count as solved, by objective name (`{ task = -200.0 }`): the run
    /// reports the env steps and seconds at which the mean of the last 10 training
    /// episodes first reached all of them (`solve.rs`). Empty: not measured.
    pub solve_threshold: BTreeMap<String, f64>,
    /// End training as soon as the run counts as solved (then evaluate as usual), as
    /// Stable-Baselines3's `StopTrainingOnRewardThreshold` does. Needs `solve_threshold`.
    pub stop_on_solve: bool,
}

impl Default for RunConfig {
    fn default() -> Self {
        Self {
            total_env_steps: 100_000,
            learner_steps_per_env_step: 0.125,
            min_replay_transitions: 1_000,
            publish_period: 1_000,
            checkpoint_period: 1_000,
            checkpoint_replay: true,
            log_period: 50,
            eval_episodes: 10,
            eval_period: 0,
            runs_dir: PathBuf::from("runs"),
            solve_threshold: BTreeMap::new(),
            stop_on_solve: false,
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
    /// How an ε-conditioned run's front is measured; required with
    /// `learner.conditioning`, refused without it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub front: Option<FrontConfig>,
}

impl TrainConfig {
    /// This config with the fields a population's members may differ in blanked
    /// (seed, ε, scalarization weights, runs folder): runs with equal keys can train
    /// as one population (`train::train_population`).
    pub fn population_key(&self) -> TrainConfig {
        let mut key = self.clone();
        key.seed = 0;
        key.learner = crate::core::algo::population::population_key(&self.learner);
        key.run.runs_dir = PathBuf::new();
        key
    }

    /// Read and validate a TOML file.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        Self::load_with(path, &[])
    }

    /// Read a TOML file (with the file its `extends` names, `extends.rs`), apply
    /// `overrides` (`dotted.path=toml_value`, e.g.
    /// `learner.mpo.batch_size=64` or `learner.objectives.1.epsilon=0.0`, where a
    /// number indexes an array), then validate.
    pub fn load_with(path: &Path, overrides: &[String]) -> Result<Self, ConfigError> {
        let mut table = extends::read_table(path)?;
        for o in overrides {
            apply_override(&mut table, o)?;
        }
        let mut cfg: TrainConfig = table
            .try_into()
            .map_err(|e| extends::schema_error(path, e))?;
        cfg.learner.seed = cfg.seed;
        cfg.validate()?;
        Ok(cfg)
    }

    /// Check the env, front, run and learner fields.
    pub fn validate(&self) -> Result<(), ConfigError> {
        self.validate_env()?;
        self.validate_front()?;
        self.validate_run()?;
        self.learner.validate()
    }

    /// The `[env]` fields: id, sizes, connection, deadlines and server addresses.
    fn validate_env(&self) -> Result<(), ConfigError> {
        if self.env.id.is_empty() {
            return invalid("env.id", "a registered env id", "\"\"".into());
        }
        if self.env.num_envs == 0 {
            return invalid("env.num_envs", ">= 1", "0".into());
        }
        if self.env.num_actors == 0 {
            return invalid("env.num_actors", ">= 1", "0".into());
        }
        self.env.connection.validate()?;
        self.env.deadlines.validate()?;
        for (i, spec) in self.env.servers.iter().enumerate() {
            match ServerSource::parse(spec) {
                Ok(_) => {}
                Err(DiscoveryError::Syntax { expected, got, .. }) => {
                    return invalid(
                        &format!("env.servers[{i}]"),
                        &expected,
                        format!("{spec:?} ({got})"),
                    );
                }
                Err(e) => return invalid(&format!("env.servers[{i}]"), FORMS, e.to_string()),
            }
        }
        if self.env.workers >= self.env.num_envs {
            return invalid(
                "env.workers",
                &format!("at most env.num_envs - 1 = {}", self.env.num_envs - 1),
                self.env.workers.to_string(),
            );
        }
        Ok(())
    }

    /// A `[front]` section exactly when the learner is ε-conditioned.
    fn validate_front(&self) -> Result<(), ConfigError> {
        match (&self.learner.conditioning, &self.front) {
            (Some(_), None) => invalid(
                "front",
                "a [front] section with reference_point when learner.conditioning is set (the run ends by measuring its front)",
                "no [front]".into(),
            ),
            (None, Some(_)) => invalid(
                "front",
                "absent unless learner.conditioning is set (a fixed-ε run has one point, not a front)",
                "a [front] section".into(),
            ),
            _ => Ok(()),
        }
    }

    /// The `[run]` fields: rates, periods and the solve threshold.
    fn validate_run(&self) -> Result<(), ConfigError> {
        let r = &self.run;
        if !(r.learner_steps_per_env_step.is_finite() && r.learner_steps_per_env_step > 0.0) {
            return invalid(
                "run.learner_steps_per_env_step",
                "> 0",
                r.learner_steps_per_env_step.to_string(),
            );
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
        if let Some((name, v)) = r.solve_threshold.iter().find(|(_, v)| !v.is_finite()) {
            return invalid(
                &format!("run.solve_threshold.{name}"),
                "finite",
                v.to_string(),
            );
        }
        if r.stop_on_solve && r.solve_threshold.is_empty() {
            return invalid(
                "run.stop_on_solve",
                "false unless run.solve_threshold names a threshold",
                "true".into(),
            );
        }
        if r.min_replay_transitions == 0 {
            return invalid("run.min_replay_transitions", ">= 1", "0".into());
        }
        Ok(())
    }

    /// Short algorithm name for run directories and tables.
    pub fn algo_name(&self) -> &'static str {
        self.learner.algorithm.short_name()
    }
}

/// A validation error naming `field`, what it must be, and what it was.
fn invalid(field: &str, requirement: &str, got: String) -> Result<(), ConfigError> {
    Err(ConfigError::Invalid {
        field: field.into(),
        requirement: requirement.into(),
        got,
    })
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
        assert_eq!(
            (cfg.env.num_envs, cfg.env.num_actors, cfg.learner.seed),
            (8, 1, 5)
        );
        assert_eq!(cfg.run, RunConfig::default());
    }

    #[test]
    fn overrides_set_nested_fields_and_array_items() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("c.toml");
        let text = "[env]\nid = \"dst\"\n[[learner.objectives]]\nname = \"time\"\nepsilon = 0.01\n[[learner.objectives]]\nname = \"treasure\"\nepsilon = 0.5\n";
        std::fs::write(&path, text).unwrap();
        let sets = [
            "learner.mpo.batch_size=64",
            "learner.objectives.1.epsilon=0.0",
            "run.solve_threshold={ treasure = 20.0 }",
            "seed=7",
        ];
        let cfg = TrainConfig::load_with(&path, &sets.map(String::from)).unwrap();
        assert_eq!(
            (
                cfg.learner.mpo.batch_size,
                cfg.learner.objectives[1].epsilon,
                cfg.seed,
                cfg.learner.seed
            ),
            (64, 0.0, 7, 7)
        );
        assert_eq!(cfg.run.solve_threshold["treasure"], 20.0);
        let err = TrainConfig::load_with(&path, &["learner.objectives.5.epsilon=0".into()])
            .unwrap_err()
            .to_string();
        assert_eq!(
            err,
            r#"--set must be an index inside the array, got "learner.objectives.5.epsilon=0""#
        );
        let err = TrainConfig::load_with(&path, &["learner.mpo.batch_size".into()])
            .unwrap_err()
            .to_string();
        assert!(err.contains("dotted.path=value"), "{err}");
        let err = TrainConfig::load_with(&path, &["learner.mpo.batch_sise=3".into()])
            .unwrap_err()
            .to_string();
        assert!(err.contains("batch_sise"), "{err}");
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
        assert_eq!(
            err,
            "env.workers must be at most env.num_envs - 1 = 3, got 4"
        );
        std::fs::write(
            &path,
            "[env]\nid = \"dst\"\nservers = [\"h:1\", \"dns:envs\"]\n",
        )
        .unwrap();
        let err = TrainConfig::load(&path).unwrap_err().to_string();
        assert_eq!(
            err,
            "env.servers[1] must be dns:NAME:PORT or dns://NAMESERVER/NAME:PORT (a DNS name \
             and a port), got \"dns:envs\" (no port in \"envs\")"
        );
        std::fs::write(&path, "[env]\nid = \"dst\"\nnum_env = 3\n").unwrap();
        let err = TrainConfig::load(&path).unwrap_err().to_string();
        assert!(err.contains("num_env"), "{err}");
    }
}
