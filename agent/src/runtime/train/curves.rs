//! The learning curves of a run (`curves.png`, `curves.svg`) from its `episodes.csv`.
//!
//! Each point is the mean return of the episodes that ended in one env-step bucket,
//! drawn at the bucket's end. A running mean over episodes drew vertical zigzags instead:
//! the B instances of a session often end episodes at the same env step (pendulum's
//! always do), and each of those was a point of its own at one x.

use std::path::Path;

use super::{TrainError, io};
use crate::report::plot::{Figure, Series, SeriesKind, tick_label};

/// About this many buckets span the run; the width is rounded to a 1-2-2.5-5 step.
const BUCKETS: u64 = 50;

/// One finished episode of `episodes.csv`.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct EpisodeEnd {
    /// The run's env steps when it ended.
    pub env_steps: u64,
    /// Undiscounted return per objective.
    pub returns: Vec<f64>,
}

/// The mean return of the episodes that ended in `(end - width, end]`.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct BucketMean {
    /// The bucket's last env step (where the point is drawn).
    pub end: u64,
    /// Per objective: the mean of the finite returns (NaN when none was finite).
    pub mean: Vec<f64>,
}

/// Learning curves from `episodes.csv`: per objective, the mean undiscounted return of
/// the episodes ending in each env-step bucket (the same buckets for every objective).
pub(super) fn plot_curves(run_dir: &Path, objectives: &[String]) -> Result<(), TrainError> {
    let path = run_dir.join("episodes.csv");
    let text = std::fs::read_to_string(&path).map_err(io(&path))?;
    let episodes = parse_episodes(&text, objectives.len());
    let Some(last) = episodes.iter().map(|e| e.env_steps).max() else {
        return Ok(());
    };
    let width = bucket_width(last);
    let buckets = bucket_means(&episodes, width);
    let series = objectives
        .iter()
        .enumerate()
        .map(|(k, name)| Series {
            label: name.clone(),
            points: buckets.iter().map(|b| (b.end as f64, b.mean[k])).collect(),
            kind: SeriesKind::Line,
        })
        .collect();
    let figure = Figure {
        title: format!(
            "training returns ({})",
            run_dir
                .file_name()
                .map(|n| n.to_string_lossy())
                .unwrap_or_default()
        ),
        x_label: "env steps".into(),
        // "mean per 1k env steps": of the episodes that ended in each bucket.
        y_label: format!(
            "episode return (mean per {} env steps)",
            tick_label(width as f64)
        ),
        series,
        log_x: false,
    };
    crate::report::plot::save(&figure, &run_dir.join("curves"))?;
    Ok(())
}

/// The rows of `episodes.csv` (`env_steps,actor,env_index,length,return_<k>...`); a row
/// whose env steps do not parse is skipped, a return that does not parse is NaN.
fn parse_episodes(text: &str, objectives: usize) -> Vec<EpisodeEnd> {
    text.lines()
        .skip(1)
        .filter_map(|line| {
            let fields: Vec<&str> = line.split(',').collect();
            let env_steps = fields.first()?.parse().ok()?;
            let returns = (0..objectives)
                .map(|k| {
                    fields
                        .get(4 + k)
                        .and_then(|v| v.parse().ok())
                        .unwrap_or(f64::NAN)
                })
                .collect();
            Some(EpisodeEnd { env_steps, returns })
        })
        .collect()
}

/// The smallest 1, 2, 2.5 or 5 times a power of ten that splits `last` env steps into
/// at most [`BUCKETS`] buckets (at least 1), so bucket ends fall on round numbers.
fn bucket_width(last: u64) -> u64 {
    let wanted = last.div_ceil(BUCKETS).max(1);
    let mut decade = 1u64;
    loop {
        // At decade 1, 5 / 2 rounds down to 2, which was just tried: no 2.5-step buckets.
        for width in [decade, 2 * decade, 5 * decade / 2, 5 * decade] {
            if width >= wanted {
                return width;
            }
        }
        decade *= 10;
    }
}

/// Per bucket `(end - width, end]` holding at least one episode, in env-step order: the
/// mean return per objective of the episodes ending there.
fn bucket_means(episodes: &[EpisodeEnd], width: u64) -> Vec<BucketMean> {
    let mut buckets: std::collections::BTreeMap<u64, Vec<&EpisodeEnd>> = Default::default();
    for e in episodes {
        // Steps 1..=width are bucket 1; a (theoretical) episode at step 0 joins it too.
        let index = e.env_steps.div_ceil(width).max(1);
        buckets.entry(index).or_default().push(e);
    }
    buckets
        .into_iter()
        .map(|(index, members)| {
            let k = members[0].returns.len();
            let mean = (0..k)
                .map(|i| {
                    let finite: Vec<f64> = members
                        .iter()
                        .map(|e| e.returns[i])
                        .filter(|v| v.is_finite())
                        .collect();
                    if finite.is_empty() {
                        f64::NAN
                    } else {
                        finite.iter().sum::<f64>() / finite.len() as f64
                    }
                })
                .collect();
            BucketMean {
                end: index * width,
                mean,
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn end(env_steps: u64, returns: &[f64]) -> EpisodeEnd {
        EpisodeEnd {
            env_steps,
            returns: returns.to_vec(),
        }
    }

    #[test]
    fn episodes_ending_at_one_step_become_one_point_per_bucket() {
        // Width 100: buckets (0, 100], (100, 200], (200, 300]. Steps 100 and 200 are the
        // last of their buckets; nothing ends in (200, 300], so no point there.
        let episodes = [
            end(100, &[1.0, -2.0]),
            end(100, &[3.0, -4.0]), // the same step: averaged, not a vertical line
            end(40, &[5.0, f64::NAN]),
            end(101, &[10.0, 0.0]),
            end(200, &[20.0, 1.0]),
            end(350, &[7.0, 7.0]),
        ];
        let buckets = bucket_means(&episodes, 100);
        let expected = [
            // (1 + 3 + 5) / 3 = 3; (-2 - 4) / 2 = -3, the NaN skipped.
            (100, [3.0, -3.0]),
            // (10 + 20) / 2 = 15; (0 + 1) / 2 = 0.5.
            (200, [15.0, 0.5]),
            (400, [7.0, 7.0]),
        ];
        assert_eq!(buckets.len(), expected.len());
        for (got, (end, mean)) in buckets.iter().zip(expected) {
            assert_eq!(got.end, end);
            assert_eq!(got.mean, mean, "bucket ending at {end}");
        }
    }

    #[test]
    fn bucket_widths_are_round_and_give_at_most_fifty_buckets() {
        // ceil(last / 50) rounded up to 1, 2, 2.5 or 5 × 10^k (2.5 only from 25 on).
        let cases = [
            (1, 1),
            (50, 1),
            (51, 2),
            (120, 5), // 3 wanted: 2.5 is not a whole step, so 5
            (30_000, 1_000),
            (1_000_000, 20_000),
            (1_000_001, 25_000), // 20 001 wanted
            (1_250_001, 50_000),
            (1_500_000, 50_000),
        ];
        for (last, width) in cases {
            assert_eq!(bucket_width(last), width, "last step {last}");
            assert!(last.div_ceil(width) <= BUCKETS);
        }
    }

    #[test]
    fn episodes_csv_rows_are_read_by_column() {
        let text = "env_steps,actor,env_index,length,return_time,return_treasure,x\n\
                    8,0,0,1,-1,0.7,-1\n\
                    16,0,1,2,-2,oops,-1.99\n\
                    ,0,1,2,-2,1,-1.99\n";
        assert_eq!(
            parse_episodes(text, 2)
                .iter()
                .map(|e| (e.env_steps, format!("{:?}", e.returns)))
                .collect::<Vec<_>>(),
            [(8, "[-1.0, 0.7]".into()), (16, "[-2.0, NaN]".into())]
        );
    }
}
