//! A front's points, how they are measured (hypervolume against a reference point,
//! EUM, IGD to a known true front, per-seed fronts) and the files that show them
//! (`points.csv`, `front.csv`, `summary.json`, `front.png`, the Fig. 5-style ratio
//! plot). `agent sweep` gives it one point per run; an ε-conditioned run, one per grid
//! point of its preference grid (whose `[front]` section is [`FrontConfig`]).

use std::collections::BTreeMap;
use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use crate::core::learner_config::ConfigError;
use crate::report::pareto::{expected_utility, hypervolume, igd, non_dominated, simplex_weights};
use crate::report::plot::PlotError;

mod report;
pub mod seeds;

/// Errors of measuring or writing a front.
#[derive(Debug, thiserror::Error)]
pub enum FrontError {
    /// The reference point or ratio plot does not fit the objectives.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// Writing a figure failed.
    #[error(transparent)]
    Plot(#[from] PlotError),
    /// A front file could not be written.
    #[error("{path}: {source}")]
    Io {
        /// File involved.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
}

fn invalid(field: &str, requirement: &str, got: impl std::fmt::Debug) -> ConfigError {
    ConfigError::Invalid {
        field: field.into(),
        requirement: requirement.into(),
        got: format!("{got:?}"),
    }
}

/// A Fig. 5-style plot: `y_objective`'s return against `setting[numerator] / setting[denominator]`.
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

/// `[front]` of an ε-conditioned run (`learner.conditioning`): how the front its
/// policy traces over the preference grid is measured (`<run>/front/`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FrontConfig {
    /// Hypervolume reference point, objective name -> value (every objective).
    pub reference_point: BTreeMap<String, f64>,
    /// A known Pareto front, objective name -> values, entry i of every list being
    /// point i: drawn on the plots, and its hypervolume and the IGD to it are reported.
    #[serde(default)]
    pub true_front: BTreeMap<String, Vec<f64>>,
    /// Optional ε-ratio plot.
    #[serde(default)]
    pub ratio_plot: Option<RatioPlot>,
    /// Hypervolume reference point of the discounted evaluation returns, objective
    /// name -> value (every objective), as MORL-Baselines measures fronts (e.g. -100
    /// per objective with gamma 0.99); when given, the run's periodic evaluations log
    /// that hypervolume too. Empty (default): not measured.
    #[serde(default)]
    pub discounted_reference_point: BTreeMap<String, f64>,
}

impl FrontConfig {
    /// `reference_point` in objective order (an error names a missing objective).
    pub fn reference(&self, objectives: &[String]) -> Result<Vec<f64>, ConfigError> {
        in_order(&self.reference_point, "reference_point", objectives)
    }

    /// `discounted_reference_point` in objective order, when given.
    pub fn discounted_reference(
        &self,
        objectives: &[String],
    ) -> Result<Option<Vec<f64>>, ConfigError> {
        if self.discounted_reference_point.is_empty() {
            return Ok(None);
        }
        let field = "discounted_reference_point";
        in_order(&self.discounted_reference_point, field, objectives).map(Some)
    }
}

/// `values` in `objectives`' order.
fn in_order(
    values: &BTreeMap<String, f64>,
    field: &str,
    objectives: &[String],
) -> Result<Vec<f64>, ConfigError> {
    objectives
        .iter()
        .map(|n| {
            values
                .get(n)
                .copied()
                .ok_or_else(|| invalid(field, "a value per objective", n))
        })
        .collect()
}

/// One trained and evaluated setting.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FrontPoint {
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
pub struct FrontSummary {
    /// Output directory.
    pub dir: PathBuf,
    /// Objective names in reward order.
    pub objectives: Vec<String>,
    /// Every run.
    pub points: Vec<FrontPoint>,
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
    /// Wall time of what measured the front: the sweep invocation that wrote it (a
    /// resume counts from its own start; `agent sweep --report`, the longest of the
    /// merged folders' own), or an ε-conditioned run's evaluation over its grid.
    pub wall_seconds: f64,
}

/// How a front is measured and drawn: a sweep file's settings, or an ε-conditioned
/// run's `[front]`.
#[derive(Debug, Clone, Copy)]
pub struct FrontReport<'a> {
    /// Title of the plots.
    pub name: &'a str,
    /// Hypervolume reference point, objective name -> value.
    pub reference_point: &'a BTreeMap<String, f64>,
    /// A known Pareto front, objective name -> values (may be empty).
    pub true_front: &'a BTreeMap<String, Vec<f64>>,
    /// The Fig. 5-style plot, when wanted.
    pub ratio_plot: Option<&'a RatioPlot>,
}

impl FrontReport<'_> {
    /// Marks the non-dominated points, measures the front (hypervolume, EUM, IGD) and
    /// writes `points.csv`, `front.csv`, `summary.json` and the plots into `dir`.
    pub fn write(
        &self,
        dir: PathBuf,
        objectives: Vec<String>,
        mut points: Vec<FrontPoint>,
        wall_seconds: f64,
    ) -> Result<FrontSummary, FrontError> {
        let reference = in_order(self.reference_point, "reference_point", &objectives)?;
        let returns: Vec<Vec<f64>> = points.iter().map(|p| p.eval_return.clone()).collect();
        for i in non_dominated(&returns) {
            points[i].on_front = true;
        }
        let true_front: Vec<Vec<f64>> = match objectives
            .iter()
            .map(|n| self.true_front.get(n))
            .collect::<Option<Vec<_>>>()
        {
            Some(columns) if !columns.is_empty() => (0..columns[0].len())
                .map(|i| columns.iter().map(|c| c[i]).collect())
                .collect(),
            _ => Vec::new(),
        };
        let known = !true_front.is_empty();
        let summary = FrontSummary {
            dir,
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
            wall_seconds,
        };
        report::write_outputs(self, &summary)?;
        Ok(summary)
    }
}
