//! `learner.conditioning`: MO-MPO conditioned on its preferences ε (issue 26). One
//! policy pi(a | s, ε) and one set of critics Q_k(s, a, ε) learn the whole grid of
//! preferences that a sweep would train one run each for; the temperatures eta_k are
//! kept per grid point (`algo/preferences.rs`).

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use super::error::{check, invalid};
use super::{Algorithm, Architecture, ConfigError, LearnerConfig};

/// The most grid points one conditioned learner keeps duals for.
pub const MAX_GRID_POINTS: usize = 4096;

/// Which preferences an ε-conditioned MO-MPO learner trains on and is evaluated at.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ConditioningConfig {
    /// Objective name -> the ε values it takes (each > 0). The grid is their product;
    /// an objective not named keeps its fixed `learner.objectives[..].epsilon`. Every
    /// episode of every env instance draws one grid point uniformly, acts with it and
    /// stores it with its transitions (as input features `preference`); the run ends by
    /// evaluating the deterministic policy at every grid point (`<run>/front/`).
    pub epsilon: BTreeMap<String, Vec<f64>>,
    /// Train every sampled snippet at a grid point drawn uniformly for it, instead of
    /// the one its episode was collected with. Rewards do not depend on ε, so every
    /// transition is data for every preference (hindsight relabelling, as CAPQL and
    /// PD-MORL do with weights); Retrace's importance weights already correct for the
    /// behaviour policy having acted with another ε.
    #[serde(default = "default_relabel")]
    pub relabel: bool,
    /// How the M-step's trust region (alpha_mu, alpha_Sigma) covers the grid:
    /// `"shared"`, one set of multipliers for the KL averaged over all states, or
    /// `"per_point"`, one set per grid point for the KL averaged over that point's
    /// states, each state's KL penalised with its own point's alpha (the temperatures
    /// are per grid point either way). The paper has no conditioned learner; shared
    /// is what a sweep's single run has.
    #[serde(default)]
    pub trust_region: GridTrustRegion,
    /// Rescale every grid point's ε vector, over all objectives, to sum to this,
    /// keeping its ratios (the preference, Fig. 5): the E-step then lets every grid
    /// point move the policy by the same total KL, where the lists as given let a
    /// point whose ε are all large pull harder on the shared network than one whose
    /// ε are small. Features, fronts and `--epsilon` keep the ε as listed. Not in the
    /// paper (which trains one ε vector per run); `None` (default): ε as listed.
    #[serde(default)]
    pub total_epsilon: Option<f64>,
}

/// Whether the grid points share the M-step's trust-region multipliers.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum GridTrustRegion {
    /// One alpha_mu and alpha_Sigma for the KL over all states.
    #[default]
    Shared,
    /// One alpha_mu and alpha_Sigma per grid point, for the KL over its states.
    PerPoint,
}

fn default_relabel() -> bool {
    true
}

impl ConditioningConfig {
    /// Checks that `learner` can be conditioned (MO-MPO with a feed-forward network)
    /// and that the grid names its objectives.
    pub fn validate_for(&self, learner: &LearnerConfig) -> Result<(), ConfigError> {
        check(
            learner.algorithm == Algorithm::MoMpo,
            "learner.conditioning",
            "used with algorithm.kind = \"mo_mpo\" only",
            learner.algorithm.short_name(),
        )?;
        check(
            !matches!(learner.network.architecture, Architecture::Mocap { .. }),
            "learner.conditioning",
            "used with a feed-forward network (the mocap torso reads its inputs by name)",
            &learner.network.architecture,
        )?;
        let names: Vec<&str> = learner.objectives.iter().map(|o| o.name.as_str()).collect();
        self.validate(&names)
    }

    /// Checks the grid against the learner's objective names.
    pub fn validate(&self, objective_names: &[&str]) -> Result<(), ConfigError> {
        check(
            !self.epsilon.is_empty(),
            "learner.conditioning.epsilon",
            "at least one objective with its list of ε values",
            &self.epsilon,
        )?;
        if let Some(total) = self.total_epsilon {
            check(
                total.is_finite() && total > 0.0,
                "learner.conditioning.total_epsilon",
                "a number > 0",
                total,
            )?;
        }
        let mut points = 1usize;
        for (name, values) in &self.epsilon {
            let field = format!("learner.conditioning.epsilon.{name}");
            if !objective_names.contains(&name.as_str()) {
                return Err(invalid(
                    &field,
                    &format!("one of learner.objectives {objective_names:?}"),
                    name,
                ));
            }
            check(!values.is_empty(), &field, "a non-empty list", values)?;
            check(
                values.iter().all(|v| v.is_finite() && *v > 0.0),
                &field,
                "ε values > 0 (an objective without influence has no grid: give it epsilon = 0 in learner.objectives)",
                values,
            )?;
            points = points.saturating_mul(values.len());
        }
        check(
            points <= MAX_GRID_POINTS,
            "learner.conditioning.epsilon",
            &format!(
                "a grid of at most {MAX_GRID_POINTS} points (the product of the lists' lengths)"
            ),
            points,
        )
    }
}
