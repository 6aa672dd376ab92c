//! ε (or weight) sweeps that trace a Pareto front (paper Sec. 5, Table 4, Fig. 5).
//!
//! A sweep file names a base run config and a grid of settings. Every setting is
//! trained with every seed, its final deterministic policy evaluated, and the
//! undiscounted evaluation returns become the sweep's points. Written under
//! `runs/sweep__<name>__<time>/`: `points.csv`, `front.csv`, `summary.json`
//! (hypervolume with the stated reference point, EUM), `front.{png,svg}` and, when
//! configured, the Fig. 5-style plot of one objective's return against an ε ratio.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::{Instant, SystemTime, UNIX_EPOCH};

mod report;
pub mod seeds;

use futures::StreamExt;
use serde::{Deserialize, Serialize};

use crate::config::{Algorithm, ConfigError, ObjectiveWeight};
use crate::metrics::format_vector;
use crate::pareto::{expected_utility, hypervolume, igd, non_dominated, simplex_weights};
use crate::run_config::TrainConfig;
use crate::train::{TrainError, TrainOptions, TrainSummary, train};
use crate::video::{VideoOptions, VideoPlan};

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

/// A Fig. 5-style plot: `y_objective`'s return against setting[numerator]/setting[denominator].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RatioPlot {
    /// Objective whose setting is the numerator.
    pub numerator: String,
    /// Objective whose setting is the denominator (one series per value of it).
    pub denominator: String,
    /// Objective whose evaluation return is plotted.
    pub y_objective: String,
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
    /// Runs trained at the same time. One run alternates actor and learner (the
    /// schedule's lockstep), so 2-3 keep two cores busy; set learner.num_threads = 1.
    /// Concurrent runs share libtorch's process-wide random generator, so only
    /// `parallel = 1` makes every run bit-reproducible.
    #[serde(default = "default_parallel")]
    pub parallel: usize,
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

/// One trained and evaluated setting.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SweepPoint {
    /// Objective name -> ε or weight.
    pub setting: BTreeMap<String, f64>,
    /// Seed of the run.
    pub seed: u64,
    /// Mean undiscounted evaluation return, in objective order.
    pub eval_return: Vec<f64>,
    /// Mean discounted evaluation return.
    pub eval_discounted_return: Vec<f64>,
    /// The run's directory.
    pub run_dir: PathBuf,
    /// Part of the non-dominated set.
    pub on_front: bool,
}

/// What a sweep reports (also `summary.json`).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SweepSummary {
    /// Output directory.
    pub dir: PathBuf,
    /// Objective names in reward order.
    pub objectives: Vec<String>,
    /// Every run.
    pub points: Vec<SweepPoint>,
    /// Reference point in objective order.
    pub reference_point: Vec<f64>,
    /// Hypervolume of the undiscounted evaluation returns of every run (the union
    /// over seeds).
    pub hypervolume: f64,
    /// Hypervolume of each seed's points on its own.
    pub seed_fronts: Vec<seeds::SeedFront>,
    /// Per setting: median and range of the evaluation returns across seeds.
    pub settings: Vec<seeds::SettingSpread>,
    /// Expected utility over evenly spread weights (100 for K = 2).
    pub expected_utility: f64,
    /// `true_front` in objective order (empty when the config gives none).
    pub true_front: Vec<Vec<f64>>,
    /// Hypervolume of the true front (the most a sweep can reach), when given.
    pub true_hypervolume: Option<f64>,
    /// Inverted generational distance of the found returns to the true front, when given.
    pub igd: Option<f64>,
    /// Wall time of the whole sweep.
    pub wall_seconds: f64,
}

fn invalid(field: &str, requirement: &str, got: impl std::fmt::Debug) -> ConfigError {
    ConfigError::Invalid {
        field: field.into(),
        requirement: requirement.into(),
        got: format!("{got:?}"),
    }
}

impl SweepConfig {
    /// Read a sweep file and the base config it names.
    pub fn load(path: &Path) -> Result<(SweepConfig, TrainConfig), ConfigError> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| invalid("sweep file", "readable", format!("{}: {e}", path.display())))?;
        let sweep: SweepConfig = toml::from_str(&text).map_err(|e| {
            invalid(
                &format!("sweep file {}", path.display()),
                "valid TOML matching the schema",
                e.to_string(),
            )
        })?;
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
        let settings = self.settings();
        if settings.is_empty() {
            return Err(invalid("grid", "a non-empty product or points", "nothing"));
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

fn setting_label(s: &BTreeMap<String, f64>) -> String {
    s.iter()
        .map(|(k, v)| format!("{k}={v}"))
        .collect::<Vec<_>>()
        .join(" ")
}

/// Run the whole sweep against `addresses`; `progress` draws a bar over the runs;
/// `video` records each run's final evaluation (`runs/<i>/<run>/videos/final.mp4`).
pub async fn sweep(
    sweep: &SweepConfig,
    base: &TrainConfig,
    addresses: &[String],
    progress: bool,
    video: Option<&VideoOptions>,
) -> Result<SweepSummary, TrainError> {
    let started = Instant::now();
    let time = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_millis())
        .unwrap_or(0);
    let dir = base
        .run
        .runs_dir
        .join(format!("sweep__{}__{time}", sweep.name));
    std::fs::create_dir_all(&dir).map_err(|source| TrainError::Io {
        path: dir.clone(),
        source,
    })?;
    let jobs: Vec<(BTreeMap<String, f64>, u64)> = sweep
        .settings()
        .into_iter()
        .flat_map(|s| sweep.seeds.iter().map(move |&seed| (s.clone(), seed)))
        .collect();
    let bar = if progress {
        indicatif::ProgressBar::new(jobs.len() as u64)
    } else {
        indicatif::ProgressBar::hidden()
    };
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{bar:30} run {pos}/{len} [{elapsed_precise}<{eta}] {msg}",
        )
        .expect("valid template"),
    );
    let runs = futures::stream::iter(jobs.into_iter().enumerate().map(|(i, (setting, seed))| {
        let (bar, dir) = (bar.clone(), dir.clone());
        async move {
            let mut cfg = apply(base, &setting, seed)?;
            // One directory per job: concurrent runs may share seed and start time.
            cfg.run.runs_dir = dir.join("runs").join(format!("{i:03}"));
            if let Some(n) = sweep.total_env_steps {
                cfg.run.total_env_steps = n;
            }
            let s: TrainSummary = train(
                cfg,
                addresses,
                TrainOptions {
                    resume: None,
                    progress: false,
                    video: video.map(|options| VideoPlan {
                        every: None,
                        options: options.clone(),
                    }),
                },
            )
            .await?;
            if let Some(signal) = &s.interrupted {
                // The signal reached every run: end the sweep instead of starting more.
                return Err(TrainError::Stopped(format!(
                    "interrupted ({signal}); run {} has its checkpoint and report",
                    s.run_dir.display()
                )));
            }
            let line = format!(
                "  {:<40} seed {seed}: eval return {}",
                setting_label(&setting),
                format_vector(&s.eval_return)
            );
            // A bar drawn to a non-terminal is hidden and would swallow println.
            if bar.is_hidden() {
                tracing::info!("{}", line.trim())
            } else {
                bar.println(line)
            }
            bar.inc(1);
            Ok::<_, TrainError>((i, setting, seed, s))
        }
    }))
    .buffer_unordered(sweep.parallel.max(1))
    .collect::<Vec<_>>()
    .await;
    let mut finished = runs.into_iter().collect::<Result<Vec<_>, _>>()?;
    finished.sort_by_key(|(i, ..)| *i);
    let objectives = finished
        .first()
        .map(|(.., s)| s.objectives.clone())
        .unwrap_or_default();
    let mut points: Vec<SweepPoint> = finished
        .into_iter()
        .map(|(_, setting, seed, s)| SweepPoint {
            setting,
            seed,
            eval_return: s.eval_return,
            eval_discounted_return: s.eval_discounted_return,
            run_dir: s.run_dir,
            on_front: false,
        })
        .collect();
    bar.finish_and_clear();
    let reference: Vec<f64> = objectives
        .iter()
        .map(|n| {
            sweep
                .reference_point
                .get(n)
                .copied()
                .ok_or_else(|| invalid("reference_point", "a value per objective", n))
        })
        .collect::<Result<_, _>>()?;
    let returns: Vec<Vec<f64>> = points.iter().map(|p| p.eval_return.clone()).collect();
    for i in non_dominated(&returns) {
        points[i].on_front = true;
    }
    let true_front: Vec<Vec<f64>> = match objectives
        .iter()
        .map(|n| sweep.true_front.get(n))
        .collect::<Option<Vec<_>>>()
    {
        Some(columns) if !columns.is_empty() => (0..columns[0].len())
            .map(|i| columns.iter().map(|c| c[i]).collect())
            .collect(),
        _ => Vec::new(),
    };
    let known = !true_front.is_empty();
    let summary = SweepSummary {
        dir: dir.clone(),
        hypervolume: hypervolume(&returns, &reference),
        seed_fronts: seeds::seed_fronts(&points, &reference),
        settings: seeds::setting_spreads(&points),
        expected_utility: expected_utility(&returns, &simplex_weights(objectives.len(), 100)),
        true_hypervolume: known.then(|| hypervolume(&true_front, &reference)),
        igd: (known && !returns.is_empty()).then(|| igd(&returns, &true_front)),
        true_front,
        reference_point: reference,
        objectives,
        points,
        wall_seconds: started.elapsed().as_secs_f64(),
    };
    report::write_outputs(sweep, &summary)?;
    Ok(summary)
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
