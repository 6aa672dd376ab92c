//! Reading a run config that starts from another: `extends = "other.toml"` (relative
//! to the file that names it) reads that file first, then this file's keys over it.
//! A preset for one task can so state only where it differs from the preset it
//! builds on (e.g. `configs/mompo/mo-hopper-conditioned.toml` on
//! `locomotion-conditioned.toml`) instead of repeating its every setting.
//!
//! Tables merge key by key, inline tables too (`reference_point = { ... }` changes
//! the keys it names); every other value replaces the base's, arrays and arrays of
//! tables (`[[learner.objectives]]`) whole, since a list's items have no names to merge
//! by. The result is one table, so a run's stored `config.toml` holds no `extends`
//! and resumes without the files it was built from.

use std::path::{Path, PathBuf};

use crate::core::learner_config::ConfigError;

/// The key that names the base file.
const EXTENDS: &str = "extends";

/// `path` read as a TOML table, with its `extends` chain resolved.
pub(super) fn read_table(path: &Path) -> Result<toml::Table, ConfigError> {
    read_chain(path, &mut Vec::new())
}

/// `seen` holds the files above `path` in the chain, to name a cycle instead of
/// recursing forever.
fn read_chain(path: &Path, seen: &mut Vec<PathBuf>) -> Result<toml::Table, ConfigError> {
    let text = std::fs::read_to_string(path).map_err(|e| {
        let (field, requirement) = match seen.last() {
            None => ("config file".into(), "readable"),
            Some(child) => (
                format!("{EXTENDS} in {}", child.display()),
                "a readable run config (relative to the file that names it)",
            ),
        };
        ConfigError::Invalid {
            field,
            requirement: requirement.into(),
            got: format!("{}: {e}", path.display()),
        }
    })?;
    let mut table: toml::Table = toml::from_str(&text).map_err(|e| schema_error(path, e))?;
    let Some(base) = table.remove(EXTENDS) else {
        return Ok(table);
    };
    let toml::Value::String(base) = base else {
        return Err(ConfigError::Invalid {
            field: format!("{EXTENDS} in {}", path.display()),
            requirement: "a string, the path of the run config this one starts from".into(),
            got: base.to_string(),
        });
    };
    let base_path = path.parent().unwrap_or(Path::new(".")).join(base);
    // Canonical paths, so that `./a.toml` and `a.toml` are one file; an unreadable one
    // keeps its name and fails on reading below.
    let key = |p: &Path| std::fs::canonicalize(p).unwrap_or_else(|_| p.to_path_buf());
    seen.push(path.to_path_buf());
    if seen.iter().any(|p| key(p) == key(&base_path)) {
        let chain: Vec<String> = seen.iter().map(|p| p.display().to_string()).collect();
        return Err(ConfigError::Invalid {
            field: format!("{EXTENDS} in {}", path.display()),
            requirement: "a chain of run configs without a cycle".into(),
            got: format!("{} -> {}", chain.join(" -> "), base_path.display()),
        });
    }
    let mut merged = read_chain(&base_path, seen)?;
    seen.pop();
    merge(&mut merged, table);
    Ok(merged)
}

/// `path` is not TOML, or its table does not deserialize as a run config.
pub(super) fn schema_error(path: &Path, e: impl std::fmt::Display) -> ConfigError {
    ConfigError::Invalid {
        field: format!("config file {}", path.display()),
        requirement: "valid TOML matching the schema".into(),
        got: e.to_string(),
    }
}

/// `over`'s keys over `base`'s: tables recursively, anything else replaced.
fn merge(base: &mut toml::Table, over: toml::Table) {
    for (key, value) in over {
        match (base.get_mut(&key), value) {
            (Some(toml::Value::Table(b)), toml::Value::Table(o)) => merge(b, o),
            (_, value) => {
                base.insert(key, value);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
        let path = dir.join(name);
        std::fs::write(&path, text).unwrap();
        path
    }

    #[test]
    fn a_file_overrides_the_keys_it_names_and_keeps_the_rest_of_its_chain() {
        let dir = tempfile::tempdir().unwrap();
        write(
            dir.path(),
            "base.toml",
            "seed = 1\n[run]\ntotal_env_steps = 100\nlog_period = 10\n\
             [front]\nreference_point = { a = -1.0, b = -2.0 }\n\
             [[learner.objectives]]\nname = \"a\"\n[[learner.objectives]]\nname = \"b\"\n",
        );
        std::fs::create_dir(dir.path().join("sub")).unwrap();
        write(
            &dir.path().join("sub"),
            "middle.toml",
            "extends = \"../base.toml\"\n[run]\nlog_period = 20\n",
        );
        let top = write(
            dir.path(),
            "top.toml",
            "extends = \"sub/middle.toml\"\nseed = 3\n[front]\nreference_point = { b = -5.0 }\n\
             [[learner.objectives]]\nname = \"c\"\n",
        );
        let expected: toml::Table = toml::from_str(
            "seed = 3\n[run]\ntotal_env_steps = 100\nlog_period = 20\n\
             [front]\nreference_point = { a = -1.0, b = -5.0 }\n\
             [[learner.objectives]]\nname = \"c\"\n",
        )
        .unwrap();
        assert_eq!(read_table(&top).unwrap(), expected);
    }

    #[test]
    fn a_missing_base_a_cycle_and_a_non_string_are_errors_naming_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let missing = write(dir.path(), "m.toml", "extends = \"nowhere.toml\"\n");
        let err = read_table(&missing).unwrap_err().to_string();
        assert!(
            err.starts_with(&format!(
                "extends in {} must be a readable",
                missing.display()
            )) && err.contains("nowhere.toml"),
            "{err}"
        );
        let a = write(dir.path(), "a.toml", "extends = \"b.toml\"\n");
        write(dir.path(), "b.toml", "extends = \"./a.toml\"\n");
        let err = read_table(&a).unwrap_err().to_string();
        assert!(
            err.contains("must be a chain of run configs without a cycle")
                && err.contains("a.toml -> ")
                && err.ends_with("./a.toml"),
            "{err}"
        );
        let number = write(dir.path(), "n.toml", "extends = 3\n");
        let err = read_table(&number).unwrap_err().to_string();
        assert!(
            err.starts_with(&format!("extends in {} must be a string", number.display()))
                && err.ends_with("got 3"),
            "{err}"
        );
    }
}
