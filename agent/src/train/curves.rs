//! The learning curves of a run (`curves.png`, `curves.svg`) from its `episodes.csv`.

use std::path::Path;

use super::{TrainError, io};
use crate::plot::{Figure, Series, SeriesKind};

/// Learning curves from `episodes.csv`: per objective, the running mean (20 episodes)
/// of the undiscounted return against env steps.
pub(super) fn plot_curves(run_dir: &Path, objectives: &[String]) -> Result<(), TrainError> {
    let path = run_dir.join("episodes.csv");
    let text = std::fs::read_to_string(&path).map_err(io(&path))?;
    let rows: Vec<Vec<f64>> = text
        .lines()
        .skip(1)
        .map(|l| {
            l.split(',')
                .map(|v| v.parse::<f64>().unwrap_or(f64::NAN))
                .collect()
        })
        .collect();
    let mut series = Vec::new();
    for (k, name) in objectives.iter().enumerate() {
        let mut points = Vec::new();
        let mut window: std::collections::VecDeque<f64> = Default::default();
        for r in &rows {
            window.push_back(r[4 + k]);
            if window.len() > 20 {
                window.pop_front();
            }
            points.push((r[0], window.iter().sum::<f64>() / window.len() as f64));
        }
        series.push(Series {
            label: name.clone(),
            points,
            kind: SeriesKind::Line,
        });
    }
    if rows.is_empty() {
        return Ok(());
    }
    let figure = Figure {
        title: format!(
            "training returns ({})",
            run_dir
                .file_name()
                .map(|n| n.to_string_lossy())
                .unwrap_or_default()
        ),
        x_label: "env steps".into(),
        y_label: "episode return (mean of 20)".into(),
        series,
        log_x: false,
    };
    crate::plot::save(&figure, &run_dir.join("curves"))?;
    Ok(())
}
