//! Sweep files (`configs/sweeps/*.toml`): the grid of ε or weight settings (paper
//! Table 4), seeds, reference point, optional ε-ratio plot and true front, validated
//! against the base run config, and how one setting is applied to it.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::core::learner_config::{Algorithm, ConfigError, ObjectiveWeight};
pub use crate::report::front::RatioPlot;
use crate::runtime::run_config::TrainConfig;

/// What the grid varies.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum GridKind {
    /// MO-MPO: the ε of each named objective.
    Epsilon,
    /// Scalarized MPO: the weight of each named objective.
    Weight,
}

/// Values of one grid axis: a list, or `{ linspace = [start, stop, count] }` as
/// Table 4 writes them (count evenly spaced values, both ends included).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum Values {
    /// Explicit values.
    List(Vec<f64>),
    /// `linspace(start, stop, count)`.
    Linspace {
        /// `[start, stop, count]`.
        linspace: (f64, f64, usize),
    },
}

impl Values {
    /// The values in order.
    pub fn expand(&self) -> Vec<f64> {
        match self {
            Values::List(v) => v.clone(),
            Values::Linspace {
                linspace: (a, b, n),
            } => match n {
                0 => Vec::new(),
                1 => vec![*a],
                n => (0..*n)
                    .map(|i| a + (b - a) * i as f64 / (n - 1) as f64)
                    .collect(),
            },
        }
    }
}

/// The settings to run: a cartesian product of named value lists and/or explicit points.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Grid {
    /// ε or weight.
    pub kind: GridKind,
    /// Objective name -> values; every combination is one setting.
    #[serde(default)]
    pub product: BTreeMap<String, Values>,
    /// Explicit settings, objective name -> value.
    #[serde(default)]
    pub points: Vec<BTreeMap<String, f64>>,
    /// `target = "source"` sets target to 1 - source in every setting
    /// (Table 4's w_task = 1 - w_penalty).
    #[serde(default)]
    pub complement: BTreeMap<String, String>,
}

/// A sweep file (`configs/sweeps/*.toml`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SweepConfig {
    /// Name used for the output directory.
    pub name: String,
    /// Base run config, relative to the sweep file.
    pub base: PathBuf,
    /// Seeds run for every setting.
    #[serde(default = "default_seeds")]
    pub seeds: Vec<u64>,
    /// Hypervolume reference point, objective name -> value.
    pub reference_point: BTreeMap<String, f64>,
    /// Override of the base's run.total_env_steps.
    #[serde(default)]
    pub total_env_steps: Option<u64>,
    /// Populations (or single runs) trained at the same time. With
    /// learner.num_threads = 1 each learner is one thread, and an off-policy run's
    /// actors step its envs while it trains, so one per core keeps the cores busy.
    /// Every run draws from its own random streams, so `parallel` changes no result.
    #[serde(default = "default_parallel")]
    pub parallel: usize,
    /// Most members of one population: jobs whose configs differ only in seed, ε or
    /// scalarization weights (unconditioned, with plain networks: any algorithm) train
    /// as one batched learner with one env session per actor (on-policy: one per
    /// member) (docs/design.md, "Populations"); each
    /// job still gets its own run folder. Unset: each such group is split evenly
    /// into `parallel` populations. 1: every job trains alone. `parallel` counts
    /// populations. `agent sweep --population N` overrides it.
    #[serde(default)]
    pub population: Option<usize>,
    /// The settings.
    pub grid: Grid,
    /// Optional ε-ratio plot.
    #[serde(default)]
    pub ratio_plot: Option<RatioPlot>,
    /// Overrides of the base config, `dotted.path=value` as `agent train --set`
    /// (e.g. `"env.kwargs.reward_scale.task=10.0"`), applied before the grid.
    #[serde(default)]
    pub set: Vec<String>,
    /// A known Pareto front (e.g. Deep Sea Treasure's ten treasures), objective name ->
    /// values, entry i of every list being point i: drawn on the front and ratio plots,
    /// and the sweep reports its hypervolume and the IGD of the found front to it.
    #[serde(default)]
    pub true_front: BTreeMap<String, Vec<f64>>,
}

fn default_seeds() -> Vec<u64> {
    vec![0]
}

fn default_parallel() -> usize {
    1
}

pub(super) fn invalid(field: &str, requirement: &str, got: impl std::fmt::Debug) -> ConfigError {
    ConfigError::Invalid {
        field: field.into(),
        requirement: requirement.into(),
        got: format!("{got:?}"),
    }
}

impl SweepConfig {
    /// Read a sweep file and the base config it names.
    pub fn load(path: &Path) -> Result<(SweepConfig, TrainConfig), ConfigError> {
        Self::load_with(path, &[])
    }

    /// [`SweepConfig::load`], with `overrides` (`agent sweep --set`) appended to the
    /// file's `set`, so that they win over it; each run's config.toml records the result.
    pub fn load_with(
        path: &Path,
        overrides: &[String],
    ) -> Result<(SweepConfig, TrainConfig), ConfigError> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| invalid("sweep file", "readable", format!("{}: {e}", path.display())))?;
        let mut sweep: SweepConfig = toml::from_str(&text).map_err(|e| {
            invalid(
                &format!("sweep file {}", path.display()),
                "valid TOML matching the schema",
                e.to_string(),
            )
        })?;
        sweep.set.extend_from_slice(overrides);
        let base_path = path.parent().unwrap_or(Path::new(".")).join(&sweep.base);
        let base = TrainConfig::load_with(&base_path, &sweep.set)?;
        sweep.validate(&base)?;
        Ok((sweep, base))
    }

    /// Every setting of the grid, product first, then the explicit points.
    pub fn settings(&self) -> Vec<BTreeMap<String, f64>> {
        let mut out = vec![BTreeMap::new()];
        if !self.grid.product.is_empty() {
            for (name, values) in &self.grid.product {
                let values = values.expand();
                out = out
                    .into_iter()
                    .flat_map(|s| {
                        values.clone().into_iter().map(move |v| {
                            let mut s = s.clone();
                            s.insert(name.clone(), v);
                            s
                        })
                    })
                    .collect();
            }
        } else {
            out.clear();
        }
        out.extend(self.grid.points.iter().cloned());
        for setting in &mut out {
            for (target, source) in &self.grid.complement {
                if let Some(&v) = setting.get(source) {
                    setting.insert(target.clone(), 1.0 - v);
                }
            }
        }
        out
    }

    fn validate(&self, base: &TrainConfig) -> Result<(), ConfigError> {
        if self.seeds.is_empty() {
            return Err(invalid("seeds", "non-empty", &self.seeds));
        }
        if self.population == Some(0) {
            return Err(invalid("population", ">= 1 when set", 0));
        }
        let settings = self.settings();
        if settings.is_empty() {
            return Err(invalid("grid", "a non-empty product or points", "nothing"));
        }
        if base.learner.conditioning.is_some() {
            return Err(invalid(
                "base",
                "a fixed-ε run config (an ε-conditioned run, learner.conditioning, traces its front by itself: run it with agent train)",
                &self.base,
            ));
        }
        let expected_kind = if base.learner.algorithm.scalarization().is_some() {
            GridKind::Weight
        } else {
            GridKind::Epsilon
        };
        if self.grid.kind != expected_kind {
            return Err(invalid(
                "grid.kind",
                &format!("{expected_kind:?} for the base algorithm"),
                self.grid.kind,
            ));
        }
        if let Some(p) = &self.ratio_plot {
            for name in [&p.numerator, &p.denominator] {
                if settings.iter().any(|s| !s.contains_key(name)) {
                    return Err(invalid(
                        "ratio_plot",
                        "objectives set in every grid setting",
                        name,
                    ));
                }
            }
        }
        for s in &settings {
            apply(base, s, 0)?;
        }
        self.validate_true_front()
    }

    fn validate_true_front(&self) -> Result<(), ConfigError> {
        if self.true_front.is_empty() {
            return Ok(());
        }
        let names: Vec<&String> = self.true_front.keys().collect();
        if !names.iter().copied().eq(self.reference_point.keys()) {
            return Err(invalid(
                "true_front",
                &format!(
                    "the objectives of reference_point, {:?}",
                    self.reference_point.keys().collect::<Vec<_>>()
                ),
                names,
            ));
        }
        let lengths: Vec<usize> = self.true_front.values().map(Vec::len).collect();
        if lengths[0] == 0 || lengths.iter().any(|&n| n != lengths[0]) {
            return Err(invalid(
                "true_front",
                "lists of one equal, non-zero length (one entry per point)",
                lengths,
            ));
        }
        for (name, values) in &self.true_front {
            if values.iter().any(|v| !v.is_finite()) {
                return Err(invalid(
                    &format!("true_front.{name}"),
                    "finite values",
                    values,
                ));
            }
        }
        Ok(())
    }
}

/// The base config with one setting and seed applied.
pub fn apply(
    base: &TrainConfig,
    setting: &BTreeMap<String, f64>,
    seed: u64,
) -> Result<TrainConfig, ConfigError> {
    let mut cfg = base.clone();
    cfg.seed = seed;
    cfg.learner.seed = seed;
    match &mut cfg.learner.algorithm {
        Algorithm::MoMpo | Algorithm::MoVmpo => {
            for (name, &epsilon) in setting {
                let o = cfg
                    .learner
                    .objectives
                    .iter_mut()
                    .find(|o| &o.name == name)
                    .ok_or_else(|| {
                        invalid("grid", "names of the base config's objectives", name)
                    })?;
                o.epsilon = epsilon;
            }
        }
        Algorithm::ScalarizedMpo { weights, .. } | Algorithm::ScalarizedVmpo { weights, .. } => {
            for (name, &weight) in setting {
                match weights.iter_mut().find(|w| &w.name == name) {
                    Some(w) => w.weight = weight,
                    None => weights.push(ObjectiveWeight {
                        name: name.clone(),
                        weight,
                    }),
                }
            }
        }
    }
    cfg.validate()?;
    Ok(cfg)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn product_and_points_expand_to_settings() {
        let text = r#"
            name = "t"
            base = "b.toml"
            reference_point = { time = -25.0, treasure = 0.0 }
            [grid]
            kind = "epsilon"
            product = { time = [0.01, 0.02], treasure = [0.1, 0.2, 0.3] }
            points = [{ time = 0.05, treasure = 0.5 }]
        "#;
        let s: SweepConfig = toml::from_str(text).unwrap();
        let settings = s.settings();
        assert_eq!(settings.len(), 2 * 3 + 1);
        assert_eq!(
            settings[0],
            BTreeMap::from([("time".into(), 0.01), ("treasure".into(), 0.1)])
        );
        assert_eq!(
            settings[6],
            BTreeMap::from([("time".into(), 0.05), ("treasure".into(), 0.5)])
        );
    }

    #[test]
    fn table_4_linspace_and_complement() {
        // Table 4, humanoid run: w_task = 1 - w_penalty, w_penalty in linspace(0, 0.15, 100).
        let text = r#"
            name = "t"
            base = "b.toml"
            reference_point = { task = 0.0, action_norm = -5000.0 }
            [grid]
            kind = "weight"
            product = { action_norm = { linspace = [0.0, 0.15, 100] } }
            complement = { task = "action_norm" }
        "#;
        let s: SweepConfig = toml::from_str(text).unwrap();
        let settings = s.settings();
        assert_eq!(settings.len(), 100);
        assert_eq!(settings[0]["action_norm"], 0.0);
        assert!((settings[99]["action_norm"] - 0.15).abs() < 1e-15);
        // Step 0.15 / 99; w_task complements it.
        assert!((settings[1]["action_norm"] - 0.15 / 99.0).abs() < 1e-15);
        assert!((settings[1]["task"] - (1.0 - 0.15 / 99.0)).abs() < 1e-15);
    }

    #[test]
    fn command_line_overrides_follow_the_files_set_and_name_a_bad_field() {
        let dir = tempfile::tempdir().unwrap();
        let smoke = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/smoke/dst.toml");
        std::fs::copy(smoke, dir.path().join("base.toml")).unwrap();
        let sweep = dir.path().join("sweep.toml");
        std::fs::write(
            &sweep,
            r#"
                name = "t"
                base = "base.toml"
                set = ["learner.mpo.batch_size=16", "learner.mpo.num_samples=5"]
                reference_point = { time = -25.0, treasure = 0.0 }
                [grid]
                kind = "epsilon"
                product = { time = [0.01] }
            "#,
        )
        .unwrap();
        let sizes = |b: &TrainConfig| (b.learner.mpo.batch_size, b.learner.mpo.num_samples);
        let (s, base) = SweepConfig::load(&sweep).unwrap();
        assert_eq!(sizes(&base), (16, 5));
        assert_eq!(s.set.len(), 2);

        // The command line's batch size wins over the file's; the file's M stays.
        let (s, base) =
            SweepConfig::load_with(&sweep, &["learner.mpo.batch_size=8".into()]).unwrap();
        assert_eq!(sizes(&base), (8, 5));
        assert_eq!(s.set.last().unwrap(), "learner.mpo.batch_size=8");

        let e = SweepConfig::load_with(&sweep, &["learner.mpo.batch_sise=8".into()])
            .unwrap_err()
            .to_string();
        assert!(e.contains("batch_sise"), "{e}");
        let e = SweepConfig::load_with(&sweep, &["learner.mpo.batch_size=0".into()])
            .unwrap_err()
            .to_string();
        // ConfigError::Invalid's "{field} must be {requirement}, got {got}" with
        // MpoConfig::validate's field and requirement.
        assert_eq!(e, "mpo.batch_size must be >= 1, got 0");
    }

    #[test]
    fn a_true_front_must_name_the_objectives_with_equal_lengths() {
        let config = |front: &str| {
            let text = format!(
                r#"
                name = "t"
                base = "b.toml"
                reference_point = {{ time = -25.0, treasure = 0.0 }}
                true_front = {front}
                [grid]
                kind = "epsilon"
                product = {{ time = [0.01] }}
            "#
            );
            toml::from_str::<SweepConfig>(&text)
                .unwrap()
                .validate_true_front()
        };
        assert!(config("{ time = [-1, -3], treasure = [0.7, 8.2] }").is_ok());
        let err = |front: &str| config(front).unwrap_err().to_string();
        let e = err("{ time = [-1], reward = [0.7] }");
        assert!(e.contains("true_front") && e.contains("reward"), "{e}");
        let e = err("{ time = [-1, -3], treasure = [0.7] }");
        assert!(e.contains("true_front") && e.contains("[2, 1]"), "{e}");
        let e = err("{ time = [], treasure = [] }");
        assert!(e.contains("non-zero"), "{e}");
        let e = err("{ time = [-1], treasure = [nan] }");
        assert!(
            e.contains("true_front.treasure") && e.contains("NaN"),
            "{e}"
        );
    }
}
