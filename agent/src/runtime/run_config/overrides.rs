//! Changing a loaded run config: `--set dotted.path=value` overrides on the TOML
//! table before it is parsed, and the check that a resumed run changes only what a
//! running run may change.

use super::TrainConfig;
use crate::core::learner_config::ConfigError;

impl TrainConfig {
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
        self.run.eval_period = from.run.eval_period;
        self.env.servers = from.env.servers.clone();
        self.env.connection = from.env.connection.clone();
        self.env.deadlines = from.env.deadlines;
        self.learner.device = from.learner.device;
    }
}

/// What `--set` (and the flags) may change on `--resume`: the budget, logging and
/// checkpoint periods, the final evaluation's length, and where the run finds its
/// servers (and how long it waits for them) and device. Everything else would make the continuation another run.
pub const RESUMABLE_FIELDS: &[&str] = &[
    "run.total_env_steps",
    "run.log_period",
    "run.checkpoint_period",
    "run.checkpoint_replay",
    "run.eval_episodes",
    "run.eval_period",
    "env.servers",
    "env.connection",
    "env.deadlines",
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
pub(super) fn apply_override(table: &mut toml::Table, text: &str) -> Result<(), ConfigError> {
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

    fn smoke() -> TrainConfig {
        let path =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/smoke/dst.toml");
        TrainConfig::load(&path).unwrap()
    }

    #[test]
    fn a_resume_may_change_the_budget_and_periods_but_nothing_else() {
        let stored = smoke();
        let mut cfg = stored.clone();
        cfg.run.total_env_steps *= 2;
        cfg.run.checkpoint_period = 7;
        cfg.env.servers = vec!["127.0.0.1:5".into()];
        cfg.check_resume_changes(&stored).unwrap();
        cfg.learner.objectives[1].epsilon = 0.5;
        let err = cfg.check_resume_changes(&stored).unwrap_err().to_string();
        assert!(
            err.starts_with(
                "learner.objectives.1.epsilon must be unchanged when resuming: the run has 1.0 \
                 (a resumed run may change only run.total_env_steps, "
            ) && err.ends_with(", got 0.5"),
            "{err}"
        );
    }
}
