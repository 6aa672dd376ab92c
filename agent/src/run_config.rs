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

use crate::config::{ConfigError, LearnerConfig};
use crate::env::connection::ConnectionConfig;
use crate::env::discovery::{DiscoveryError, FORMS, ServerSource};

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
    /// Off-policy: checkpoints hold the replay's contents (appended as segments under
    /// `<run>/replay/`), so a resume samples from the replay the run had. `false`
    /// keeps checkpoints small; a resume then refills `min_replay_transitions` and
    /// goes on at the ratio from there (no catch-up burst). On-policy: the queued
    /// unrolls (at most about a batch) are kept or, with `false`, dropped.
    pub checkpoint_replay: bool,
    /// Learner steps between metric records.
    pub log_period: u64,
    /// Episodes of the final evaluation (deterministic policy).
    pub eval_episodes: usize,
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
            publish_period: 1,
            checkpoint_period: 1_000,
            checkpoint_replay: true,
            log_period: 50,
            eval_episodes: 10,
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
}

impl TrainConfig {
    /// Read and validate a TOML file.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        Self::load_with(path, &[])
    }

    /// Read a TOML file, apply `overrides` (`dotted.path=toml_value`, e.g.
    /// `learner.mpo.batch_size=64` or `learner.objectives.1.epsilon=0.0`, where a
    /// number indexes an array), then validate.
    pub fn load_with(path: &Path, overrides: &[String]) -> Result<Self, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|e| ConfigError::Invalid {
            field: "config file".into(),
            requirement: "readable".into(),
            got: format!("{}: {e}", path.display()),
        })?;
        let schema_error = |e: toml::de::Error| ConfigError::Invalid {
            field: format!("config file {}", path.display()),
            requirement: "valid TOML matching the schema".into(),
            got: e.to_string(),
        };
        let mut table: toml::Table = toml::from_str(&text).map_err(schema_error)?;
        for o in overrides {
            apply_override(&mut table, o)?;
        }
        let mut cfg: TrainConfig = table.try_into().map_err(schema_error)?;
        cfg.learner.seed = cfg.seed;
        cfg.validate()?;
        Ok(cfg)
    }

    /// Check the run and learner fields.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let invalid = |field: &str, requirement: &str, got: String| {
            Err(ConfigError::Invalid {
                field: field.into(),
                requirement: requirement.into(),
                got,
            })
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
        self.env.connection.validate()?;
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
        self.learner.validate()
    }

    /// Refuse what a resumed run may not change: every field but
    /// [`RESUMABLE_FIELDS`] must be as in `stored` (the run's `config.toml`); the
    /// error names the first that is not, with both values.
    pub fn check_resume_changes(&self, stored: &TrainConfig) -> Result<(), ConfigError> {
        let as_value = |cfg: &TrainConfig| {
            toml::Value::try_from(cfg).map_err(|e| ConfigError::Invalid {
                field: "config".into(),
                requirement: "representable as TOML".into(),
                got: e.to_string(),
            })
        };
        // The stored config with this one's resumable fields must be this one.
        let mut allowed = stored.clone();
        allowed.copy_resumable(self);
        match first_difference("", &as_value(&allowed)?, &as_value(self)?) {
            Some(d) => Err(ConfigError::Invalid {
                field: d.path,
                requirement: format!(
                    "unchanged when resuming: the run has {} (a resumed run may change only {})",
                    d.old,
                    RESUMABLE_FIELDS.join(", ")
                ),
                got: d.new,
            }),
            None => Ok(()),
        }
    }

    fn copy_resumable(&mut self, from: &TrainConfig) {
        self.run.total_env_steps = from.run.total_env_steps;
        self.run.log_period = from.run.log_period;
        self.run.checkpoint_period = from.run.checkpoint_period;
        self.run.checkpoint_replay = from.run.checkpoint_replay;
        self.run.eval_episodes = from.run.eval_episodes;
        self.env.servers = from.env.servers.clone();
        self.env.connection = from.env.connection.clone();
        self.learner.device = from.learner.device;
    }

    /// Short algorithm name for run directories and tables.
    pub fn algo_name(&self) -> &'static str {
        self.learner.algorithm.short_name()
    }
}

/// What `--set` (and the flags) may change on `--resume`: the budget, logging and
/// checkpoint periods, the final evaluation's length, and where the run finds its
/// servers and device. Everything else would make the continuation another run.
pub const RESUMABLE_FIELDS: &[&str] = &[
    "run.total_env_steps",
    "run.log_period",
    "run.checkpoint_period",
    "run.checkpoint_replay",
    "run.eval_episodes",
    "env.servers",
    "env.connection",
    "learner.device",
];

/// Where two configs first differ, with both values as TOML.
#[derive(Debug)]
struct Difference {
    path: String,
    old: String,
    new: String,
}

fn first_difference(path: &str, old: &toml::Value, new: &toml::Value) -> Option<Difference> {
    let join = |key: &str| {
        if path.is_empty() {
            key.to_string()
        } else {
            format!("{path}.{key}")
        }
    };
    match (old, new) {
        (toml::Value::Table(a), toml::Value::Table(b)) => {
            let keys: std::collections::BTreeSet<&String> = a.keys().chain(b.keys()).collect();
            keys.into_iter().find_map(|k| match (a.get(k), b.get(k)) {
                (Some(x), Some(y)) => first_difference(&join(k), x, y),
                (x, y) => Some(Difference {
                    path: join(k),
                    old: x.map_or("nothing".into(), ToString::to_string),
                    new: y.map_or("nothing".into(), ToString::to_string),
                }),
            })
        }
        (toml::Value::Array(a), toml::Value::Array(b)) if a.len() == b.len() => a
            .iter()
            .zip(b)
            .enumerate()
            .find_map(|(i, (x, y))| first_difference(&join(&i.to_string()), x, y)),
        _ if old == new => None,
        _ => Some(Difference {
            path: path.to_string(),
            old: old.to_string(),
            new: new.to_string(),
        }),
    }
}

/// Sets `dotted.path=value` in `table`; the value is TOML (`64`, `1e-3`, `"dst"`,
/// `{ task = -200.0 }`), and a path segment that is a number indexes an array.
fn apply_override(table: &mut toml::Table, text: &str) -> Result<(), ConfigError> {
    let bad = |requirement: &str| ConfigError::Invalid {
        field: "--set".into(),
        requirement: requirement.into(),
        got: format!("{text:?}"),
    };
    let (path, value) = text
        .split_once('=')
        .ok_or_else(|| bad("dotted.path=value"))?;
    let value: toml::Value = toml::from_str::<toml::Table>(&format!("v = {value}"))
        .map_err(|_| bad("a TOML value after '=' (strings in quotes)"))?
        .remove("v")
        .ok_or_else(|| bad("a value"))?;
    let mut node = table;
    let keys: Vec<&str> = path.trim().split('.').collect();
    let (last, parents) = keys.split_last().ok_or_else(|| bad("a path"))?;
    // Walk tables by name; a numeric segment picks an array's item, which must be a table.
    let mut segments = parents.iter().peekable();
    while let Some(key) = segments.next() {
        let child = node
            .entry(key.to_string())
            .or_insert_with(|| toml::Value::Table(toml::Table::new()));
        node = match child {
            toml::Value::Table(t) => t,
            toml::Value::Array(items) => {
                let index = segments
                    .next()
                    .ok_or_else(|| bad("an array item's field, e.g. objectives.1.epsilon"))?;
                let i: usize = index
                    .parse()
                    .map_err(|_| bad("a number to index an array"))?;
                match items.get_mut(i) {
                    Some(toml::Value::Table(t)) => t,
                    Some(_) => return Err(bad("an array of tables")),
                    None => return Err(bad("an index inside the array")),
                }
            }
            _ => return Err(bad("a path through tables and arrays")),
        };
    }
    node.insert(last.to_string(), value);
    Ok(())
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
