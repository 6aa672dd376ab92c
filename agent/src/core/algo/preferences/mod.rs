//! The preference grid of ε-conditioned MO-MPO (issue 26): the G points ε_g (a
//! product of per-objective lists, `learner.conditioning.epsilon`), the F input
//! features phi(ε) the policy and critics read after the observation, and the
//! per-state E-step inputs (eq. 34 solved separately for every grid point).
//!
//! Features: for each of the F conditioned objectives, log ε mapped affinely so that
//! the list's smallest value is -1 and its largest +1 (a one-value list gives 0).
//! The log makes ratios, which is what a preference is in MO-MPO (Fig. 5), equally
//! spaced; an ε between or beyond the grid's values maps to a point between or
//! beyond them, so a trained policy can be asked for any preference.
//!
//! Grid points are ordered as the product of the lists in the order of the learner's
//! objectives, the last objective varying fastest.
//!
//! Shape legend: G grid points, K objectives (E-step order), F conditioned
//! objectives, N states, B snippets, T snippet length.

use std::collections::BTreeMap;

use tch::{Device, Kind, Tensor};

use super::objectives::{BoundObjective, BoundObjectives, LearnerDims};
use crate::core::learner_config::{ConditioningConfig, ConfigError, GridTrustRegion};
use crate::core::nets::ActionKind;
use crate::core::random::RandomStream;

/// One conditioned objective: its place among the K and its feature map.
#[derive(Debug, Clone, PartialEq)]
struct Axis {
    /// Index among the learner's K objectives.
    objective: usize,
    /// Centre of log ε over the list.
    center: f64,
    /// Half the range of log ε over the list (1 for a one-value list).
    half_range: f64,
}

/// The grid of preferences a conditioned learner trains and is evaluated on.
#[derive(Debug, Clone, PartialEq)]
pub struct PreferenceGrid {
    /// Objective names in E-step order (K).
    names: Vec<String>,
    /// `[G][K]`: ε of every objective at every grid point.
    points: Vec<Vec<f64>>,
    /// The F conditioned objectives.
    axes: Vec<Axis>,
}

impl PreferenceGrid {
    /// The grid of `cfg` over the bound objectives (whose fixed ε fill the objectives
    /// `cfg` does not name). Names are checked by `ConditioningConfig::validate`.
    pub fn new(cfg: &ConditioningConfig, objectives: &[BoundObjective]) -> Self {
        let mut points = vec![objectives.iter().map(|o| o.epsilon).collect::<Vec<_>>()];
        let mut axes = Vec::new();
        for (k, o) in objectives.iter().enumerate() {
            let Some(values) = cfg.epsilon.get(&o.name) else {
                continue;
            };
            let logs: Vec<f64> = values.iter().map(|v| v.ln()).collect();
            let (lo, hi) = logs
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &l| {
                    (lo.min(l), hi.max(l))
                });
            let half = (hi - lo) / 2.0;
            axes.push(Axis {
                objective: k,
                center: (lo + hi) / 2.0,
                half_range: if half > 0.0 { half } else { 1.0 },
            });
            points = points
                .into_iter()
                .flat_map(|p| {
                    values.iter().map(move |&v| {
                        let mut p = p.clone();
                        p[k] = v;
                        p
                    })
                })
                .collect();
        }
        Self {
            names: objectives.iter().map(|o| o.name.clone()).collect(),
            points,
            axes,
        }
    }

    /// Number of grid points G.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// Whether the grid is empty (never: a grid has at least one point).
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// Number of input features F.
    pub fn num_features(&self) -> usize {
        self.axes.len()
    }

    /// ε of grid point `g`, in E-step order.
    pub fn epsilon(&self, g: usize) -> &[f64] {
        &self.points[g]
    }

    /// Grid point `g` as objective name -> ε of every objective (a sweep's setting, so
    /// that a ratio plot finds fixed objectives too).
    pub fn setting(&self, g: usize) -> BTreeMap<String, f64> {
        self.names
            .iter()
            .cloned()
            .zip(self.points[g].iter().copied())
            .collect()
    }

    /// The features of a full ε vector (E-step order), also one off the grid.
    pub fn features_of(&self, epsilon: &[f64]) -> Vec<f32> {
        self.axes
            .iter()
            .map(|a| ((epsilon[a.objective].ln() - a.center) / a.half_range) as f32)
            .collect()
    }

    /// The features of grid point `g`.
    pub fn features(&self, g: usize) -> Vec<f32> {
        self.features_of(&self.points[g])
    }

    /// The grid point a conditioned policy is evaluated at when no preference is
    /// asked for (the final evaluation, videos, `agent eval` without `--epsilon`):
    /// the middle one in grid order.
    pub fn default_point(&self) -> usize {
        self.points.len() / 2
    }

    /// The features of [`PreferenceGrid::default_point`].
    pub fn default_features(&self) -> Vec<f32> {
        self.features(self.default_point())
    }

    /// A grid point drawn uniformly.
    pub fn draw(&self, stream: &mut RandomStream) -> usize {
        stream.below(self.points.len() as u64) as usize
    }

    /// The full ε vector for a setting that names some conditioned objectives (the
    /// others keep the grid's first value, fixed objectives their ε); an error names
    /// an objective that is not conditioned.
    pub fn epsilon_for(&self, setting: &BTreeMap<String, f64>) -> Result<Vec<f64>, String> {
        let mut eps = self.points[0].clone();
        for (name, &value) in setting {
            let axis = self
                .axes
                .iter()
                .find(|a| self.names[a.objective] == *name)
                .ok_or_else(|| {
                    format!(
                        "{name:?} is not a conditioned objective (conditioned: {:?})",
                        self.conditioned_names()
                    )
                })?;
            if !(value.is_finite() && value > 0.0) {
                return Err(format!("ε of {name} must be > 0, got {value}"));
            }
            eps[axis.objective] = value;
        }
        Ok(eps)
    }

    /// ε of the conditioned objectives at grid point `g` (the order of
    /// `conditioned_names`).
    pub fn conditioned_epsilon(&self, g: usize) -> Vec<f64> {
        self.axes
            .iter()
            .map(|a| self.points[g][a.objective])
            .collect()
    }

    /// Names of the conditioned objectives, in E-step order.
    pub fn conditioned_names(&self) -> Vec<&str> {
        self.axes
            .iter()
            .map(|a| self.names[a.objective].as_str())
            .collect()
    }

    /// Observation rows `[R, O]` with each row's features appended: `[R, O + F]`.
    pub fn append(&self, obs: &[f32], obs_dim: usize, rows: &[usize]) -> Vec<f32> {
        let f = self.num_features();
        let mut out = Vec::with_capacity(rows.len() * (obs_dim + f));
        for (r, &g) in rows.iter().enumerate() {
            out.extend_from_slice(&obs[r * obs_dim..(r + 1) * obs_dim]);
            out.extend(self.features(g));
        }
        out
    }

    /// `[G, K]` ε table on `device`.
    pub fn epsilon_table(&self, device: Device) -> Tensor {
        let flat: Vec<f32> = self.points.iter().flatten().map(|&v| v as f32).collect();
        Tensor::from_slice(&flat)
            .reshape([self.len() as i64, self.names.len() as i64])
            .to_device(device)
    }

    /// `[G, K]` ε table as the E-step uses it: as listed, or each row rescaled to sum
    /// to `total` (`learner.conditioning.total_epsilon`), keeping its ratios.
    pub fn estep_epsilon_table(&self, total: Option<f64>, device: Device) -> Tensor {
        let listed = self.epsilon_table(device);
        match total {
            Some(total) => &listed * (total / listed.sum_dim_intlist(-1, true, Kind::Float)),
            None => listed,
        }
    }

    /// `[G, F]` feature table on `device`.
    pub fn feature_table(&self, device: Device) -> Tensor {
        let flat: Vec<f32> = (0..self.len()).flat_map(|g| self.features(g)).collect();
        Tensor::from_slice(&flat)
            .reshape([self.len() as i64, self.num_features() as i64])
            .to_device(device)
    }
}

/// What an ε-conditioned learner adds (`learner.conditioning`).
#[derive(Debug)]
pub(crate) struct Conditioned {
    /// The grid of preferences.
    pub grid: PreferenceGrid,
    /// `[G, K]` ε of every grid point as the E-step uses it (rescaled to
    /// `total_epsilon` when set).
    pub epsilon: Tensor,
    /// `[G, F]` input features of every grid point.
    pub features: Tensor,
    /// Train each snippet at a freshly drawn grid point.
    pub relabel: bool,
    /// Whether the grid points share the M-step's trust region.
    pub trust_region: GridTrustRegion,
}

impl Conditioned {
    /// The grid of `config` over the bound objectives, for a learner whose
    /// observations end with the grid's features.
    pub(crate) fn new(
        config: &ConditioningConfig,
        bound: &BoundObjectives,
        dims: &LearnerDims,
        device: Device,
    ) -> Result<Self, ConfigError> {
        let grid = PreferenceGrid::new(config, &bound.objectives);
        if dims.preference_features() != grid.num_features() {
            return Err(ConfigError::Invalid {
                field: "learner.conditioning".into(),
                requirement: format!(
                    "observations that end with {} preference features (LearnerDims::with_preference_features)",
                    grid.num_features()
                ),
                got: format!("{} features", dims.preference_features()),
            });
        }
        if config.trust_region == GridTrustRegion::PerPoint
            && matches!(dims.action, ActionKind::Discrete { .. })
        {
            return Err(ConfigError::Invalid {
                field: "learner.conditioning.trust_region".into(),
                requirement: "\"shared\" for a discrete action space (the per-grid-point trust region is kept for Gaussian policies)".into(),
                got: "\"per_point\"".into(),
            });
        }
        Ok(Self {
            epsilon: grid.estep_epsilon_table(config.total_epsilon, device),
            features: grid.feature_table(device),
            relabel: config.relabel,
            trust_region: config.trust_region,
            grid,
        })
    }
}

/// `task=0.1,action_norm=0.02` as objective name -> ε (the `--epsilon` flag).
pub fn parse_setting(text: &str) -> Result<BTreeMap<String, f64>, String> {
    let mut out = BTreeMap::new();
    for pair in text.split(',').map(str::trim).filter(|p| !p.is_empty()) {
        let (name, value) = pair
            .split_once('=')
            .ok_or_else(|| format!("expected NAME=EPS pairs separated by commas, got {pair:?}"))?;
        let value: f64 = value.trim().parse().map_err(|e| {
            format!(
                "ε of {:?} must be a number, got {value:?} ({e})",
                name.trim()
            )
        })?;
        if out.insert(name.trim().to_string(), value).is_some() {
            return Err(format!(
                "{:?} is given more than once in {text:?}",
                name.trim()
            ));
        }
    }
    if out.is_empty() {
        return Err(format!(
            "expected NAME=EPS pairs, e.g. task=0.1,action_norm=0.02, got {text:?}"
        ));
    }
    Ok(out)
}

/// Which grid point each state of a batch is trained at, and the per-state E-step
/// inputs that follow from it.
#[derive(Debug)]
pub struct StatePreferences {
    /// `[N]` int64 grid index of every state.
    pub index: Tensor,
    /// `[N, K]` ε of every state.
    pub epsilon: Tensor,
    /// `[N]` 1 / (states of the batch at the same grid point): each grid point's
    /// temperature dual averages over its own states (eq. 34 per grid point).
    pub state_weight: Tensor,
    /// `[G]` float: how many of the N states are at each grid point.
    pub counts: Tensor,
}

impl StatePreferences {
    /// Per-state inputs for grid indices `index [N]`, given the `[G, K]` ε table.
    pub fn new(index: Tensor, epsilon_table: &Tensor) -> Self {
        let g = epsilon_table.size()[0];
        let counts = index.bincount::<Tensor>(None, g).to_kind(Kind::Float);
        let state_weight = counts.clamp_min(1.0).reciprocal().index_select(0, &index);
        Self {
            epsilon: epsilon_table.index_select(0, &index),
            index,
            state_weight,
            counts,
        }
    }

    /// The same for a subset of the states (`rows [N']`).
    pub fn rows(&self, rows: &Tensor, epsilon_table: &Tensor) -> Self {
        Self::new(self.index.index_select(0, rows), epsilon_table)
    }

    /// `x [.., N, D]` averaged over each grid point's states: `[.., G, D]`, 0 at a
    /// point without states in the batch.
    pub fn mean_per_point(&self, x: &Tensor) -> Tensor {
        let mut size = x.size();
        let n = size.len() - 2;
        size[n] = self.counts.size()[0];
        Tensor::zeros(size.as_slice(), (x.kind(), x.device())).index_add(
            n as i64,
            &self.index,
            &(x * self.state_weight.unsqueeze(-1)),
        )
    }

    /// `[G]` each grid point's share of the N states (summing to 1).
    pub fn share(&self) -> Tensor {
        &self.counts / self.counts.sum(Kind::Float)
    }

    /// `[G]` 1 at the grid points with states in the batch, 0 elsewhere.
    pub fn present(&self) -> Tensor {
        self.counts.gt(0.0).to_kind(Kind::Float)
    }

    /// Per-state temperatures `[N, K]` from the `[G, K]` table.
    pub fn temperature(&self, table: &Tensor) -> Tensor {
        table.index_select(0, &self.index)
    }
}

/// Rewrites the preference features of a batch's observations `[T+1, B, O + F]` to
/// grid points `index [B]` (one per snippet), in place of those it was collected with.
pub fn relabel(observations: &Tensor, index: &Tensor, feature_table: &Tensor) -> Tensor {
    let size = observations.size();
    let f = feature_table.size()[1];
    let o = size[2] - f;
    let features = feature_table
        .index_select(0, index)
        .unsqueeze(0)
        .expand([size[0], size[1], f], false);
    Tensor::cat(&[observations.narrow(2, 0, o), features], 2)
}

/// The grid point of every snippet, read back from its stored features
/// `[T+1, B, O + F]` (its first state's, the nearest grid point) -> `[B]` int64.
pub fn collected_index(observations: &Tensor, feature_table: &Tensor) -> Tensor {
    let f = feature_table.size()[1];
    let o = observations.size()[2] - f;
    let stored = observations.get(0).narrow(1, o, f);
    // [B, G] squared distances; the stored values are the table's own, so the minimum is 0.
    (stored.unsqueeze(1) - feature_table.unsqueeze(0))
        .square()
        .sum_dim_intlist(-1, false, Kind::Float)
        .argmin(1, false)
}

#[cfg(test)]
mod tests;
