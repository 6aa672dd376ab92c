//! A sweep across seeds: per setting, the median and range of each objective's
//! evaluation return; per seed, the hypervolume of that seed's front. A front from
//! one seed is one sample; these make the spread visible beside the union's figures.

use std::collections::BTreeMap;

use serde::Serialize;

use super::FrontPoint;
use crate::report::pareto::hypervolume;

/// One setting's evaluation returns across its seeds.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SettingSpread {
    /// Objective name -> ε or weight.
    pub setting: BTreeMap<String, f64>,
    /// Seeds run for it.
    pub seeds: usize,
    /// Per objective: the median over seeds (mean of the middle two for an even count).
    pub median: Vec<f64>,
    /// Per objective: the smallest return over seeds.
    pub min: Vec<f64>,
    /// Per objective: the largest return over seeds.
    pub max: Vec<f64>,
}

/// One seed's front.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SeedFront {
    /// The seed.
    pub seed: u64,
    /// Hypervolume of that seed's points (every setting) above the sweep's reference.
    pub hypervolume: f64,
}

/// Median of a non-empty list (mean of the middle two for an even count).
pub fn median(values: &[f64]) -> f64 {
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        (v[n / 2 - 1] + v[n / 2]) / 2.0
    }
}

/// Spread per setting, in the order settings first appear in `points`.
pub fn setting_spreads(points: &[FrontPoint]) -> Vec<SettingSpread> {
    // Settings in first-seen order, each with the indices of its points.
    let mut order: Vec<&BTreeMap<String, f64>> = Vec::new();
    for p in points {
        if !order.contains(&&p.setting) {
            order.push(&p.setting);
        }
    }
    order
        .into_iter()
        .map(|setting| {
            let returns: Vec<&Vec<f64>> = points
                .iter()
                .filter(|p| &p.setting == setting)
                .map(|p| &p.eval_return)
                .collect();
            let k = returns[0].len();
            let column = |i: usize| returns.iter().map(|r| r[i]).collect::<Vec<f64>>();
            SettingSpread {
                setting: setting.clone(),
                seeds: returns.len(),
                median: (0..k).map(|i| median(&column(i))).collect(),
                min: (0..k)
                    .map(|i| column(i).into_iter().fold(f64::INFINITY, f64::min))
                    .collect(),
                max: (0..k)
                    .map(|i| column(i).into_iter().fold(f64::NEG_INFINITY, f64::max))
                    .collect(),
            }
        })
        .collect()
}

/// Hypervolume of each seed's points, by seed.
pub fn seed_fronts(points: &[FrontPoint], reference: &[f64]) -> Vec<SeedFront> {
    let mut by_seed: BTreeMap<u64, Vec<Vec<f64>>> = BTreeMap::new();
    for p in points {
        by_seed
            .entry(p.seed)
            .or_default()
            .push(p.eval_return.clone());
    }
    by_seed
        .into_iter()
        .map(|(seed, returns)| SeedFront {
            seed,
            hypervolume: hypervolume(&returns, reference),
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn point(eps: f64, seed: u64, ret: [f64; 2]) -> FrontPoint {
        FrontPoint {
            setting: BTreeMap::from([("treasure".to_string(), eps)]),
            seed,
            eval_return: ret.to_vec(),
            eval_discounted_return: ret.to_vec(),
            run_dir: Default::default(),
            on_front: false,
        }
    }

    #[test]
    fn spreads_and_seed_hypervolumes() {
        let points = [
            point(0.1, 0, [-5.0, 11.5]),
            point(0.1, 1, [-3.0, 8.2]),
            point(0.1, 2, [-7.0, 14.0]),
            point(0.5, 0, [-19.0, 23.7]),
            point(0.5, 1, [-1.0, 0.7]),
        ];
        let spreads = setting_spreads(&points);
        assert_eq!(spreads.len(), 2);
        // Setting 0.1: times -5, -3, -7 -> median -5, range [-7, -3]; treasures 11.5, 8.2, 14.
        assert_eq!(spreads[0].seeds, 3);
        assert_eq!(spreads[0].median, vec![-5.0, 11.5]);
        assert_eq!(spreads[0].min, vec![-7.0, 8.2]);
        assert_eq!(spreads[0].max, vec![-3.0, 14.0]);
        // Setting 0.5, two seeds: the median is the mean of both: (-19 - 1)/2, (23.7 + 0.7)/2.
        assert_eq!(spreads[1].median, vec![-10.0, 12.2]);
        // Seed 0: points (-5, 11.5), (-19, 23.7) above (-25, 0):
        // (-5 + 25) * 11.5 + (-19 + 25) * (23.7 - 11.5) = 230 + 73.2 = 303.2.
        // Seed 1: (-3, 8.2), (-1, 0.7): 22 * 8.2 + (24 - 22) * 0.7 = 180.4 + 1.4 = 181.8.
        // Seed 2: (-7, 14): 18 * 14 = 252.
        let fronts = seed_fronts(&points, &[-25.0, 0.0]);
        let hv: Vec<(u64, f64)> = fronts.iter().map(|f| (f.seed, f.hypervolume)).collect();
        for ((seed, got), (want_seed, want)) in hv.iter().zip([(0, 303.2), (1, 181.8), (2, 252.0)])
        {
            assert_eq!(*seed, want_seed);
            assert!((got - want).abs() < 1e-9, "seed {seed}: {got} vs {want}");
        }
    }
}
