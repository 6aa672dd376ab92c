//! How a front is measured and drawn: the hypervolume reference point, a known true
//! front and the Fig. 5-style ratio plot. A sweep file has these fields at its top
//! level; an ε-conditioned run has them in its `[front]` section.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

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
}
