//! Figures for fronts and learning curves, written as PNG and SVG with plotters.
//!
//! The font is embedded (DejaVu Sans, `agent/assets/`), so rendering needs no
//! system font libraries.

use std::path::{Path, PathBuf};
use std::sync::Once;

use plotters::coord::Shift;
use plotters::prelude::*;

/// How a series is drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SeriesKind {
    /// Unconnected markers (fronts, sweep points).
    Markers,
    /// A polyline (learning curves).
    Line,
}

/// One labelled set of (x, y) points.
#[derive(Debug, Clone, PartialEq)]
pub struct Series {
    /// Legend entry.
    pub label: String,
    /// Points in drawing order.
    pub points: Vec<(f64, f64)>,
    /// Markers or line.
    pub kind: SeriesKind,
}

/// A 2-D figure: axes labels, title and series.
#[derive(Debug, Clone, PartialEq)]
pub struct Figure {
    /// Caption above the plot.
    pub title: String,
    /// Label of the horizontal axis.
    pub x_label: String,
    /// Label of the vertical axis.
    pub y_label: String,
    /// Series drawn in order, each in its own colour.
    pub series: Vec<Series>,
    /// Logarithmic x axis (e.g. ε ratios).
    pub log_x: bool,
}

/// Errors while drawing or writing a figure.
#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    /// plotters failed (backend or file error).
    #[error("plot {path}: {message}")]
    Draw {
        /// File being written.
        path: PathBuf,
        /// plotters' message.
        message: String,
    },
    /// The figure has no finite points to scale the axes by.
    #[error("plot {0}: no finite points to draw")]
    Empty(PathBuf),
}

static FONT: Once = Once::new();

fn register_font() {
    FONT.call_once(|| {
        let bytes: &'static [u8] = include_bytes!("../assets/DejaVuSans.ttf");
        plotters::style::register_font("sans-serif", FontStyle::Normal, bytes)
            .unwrap_or_else(|_| panic!("embedded DejaVuSans.ttf is a valid font"));
    });
}

/// Write `<stem>.png` and `<stem>.svg`; returns both paths.
pub fn save(figure: &Figure, stem: &Path) -> Result<Vec<PathBuf>, PlotError> {
    register_font();
    let png = stem.with_extension("png");
    let svg = stem.with_extension("svg");
    let err = |path: &Path| {
        let path = path.to_path_buf();
        move |e: Box<dyn std::error::Error>| PlotError::Draw {
            path: path.clone(),
            message: e.to_string(),
        }
    };
    {
        let root = BitMapBackend::new(&png, (900, 600)).into_drawing_area();
        draw(figure, &root, &png).map_err(err(&png))??;
        root.present().map_err(|e| err(&png)(Box::new(e)))?;
    }
    {
        let root = SVGBackend::new(&svg, (900, 600)).into_drawing_area();
        draw(figure, &root, &svg).map_err(err(&svg))??;
        root.present().map_err(|e| err(&svg)(Box::new(e)))?;
    }
    Ok(vec![png, svg])
}

type DrawResult = Result<Result<(), PlotError>, Box<dyn std::error::Error>>;

fn draw<DB: DrawingBackend>(
    figure: &Figure,
    root: &DrawingArea<DB, Shift>,
    path: &Path,
) -> DrawResult
where
    DB::ErrorType: 'static,
{
    let finite: Vec<(f64, f64)> = figure
        .series
        .iter()
        .flat_map(|s| s.points.iter().copied())
        .filter(|(x, y)| x.is_finite() && y.is_finite() && (!figure.log_x || *x > 0.0))
        .collect();
    if finite.is_empty() {
        return Ok(Err(PlotError::Empty(path.to_path_buf())));
    }
    let (mut x0, mut x1, mut y0, mut y1) = finite.iter().fold(
        (
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
        ),
        |(a, b, c, d), &(x, y)| (a.min(x), b.max(x), c.min(y), d.max(y)),
    );
    // Pad so markers on the boundary stay visible; keep a degenerate range drawable.
    let pad = |lo: &mut f64, hi: &mut f64, log: bool| {
        if log {
            *lo /= 1.5;
            *hi *= 1.5;
        } else {
            let span = (*hi - *lo).max(1e-9);
            *lo -= 0.05 * span;
            *hi += 0.05 * span;
        }
    };
    pad(&mut x0, &mut x1, figure.log_x);
    pad(&mut y0, &mut y1, false);
    root.fill(&WHITE)?;
    let mut builder = ChartBuilder::on(root);
    builder
        .caption(&figure.title, ("sans-serif", 24))
        .margin(16)
        .x_label_area_size(48)
        .y_label_area_size(64);
    let palette = |i: usize| Palette99::pick(i).to_rgba();
    macro_rules! body {
        ($chart:expr) => {{
            let mut chart = $chart;
            chart
                .configure_mesh()
                .x_desc(figure.x_label.as_str())
                .y_desc(figure.y_label.as_str())
                .label_style(("sans-serif", 14))
                .draw()?;
            for (i, s) in figure.series.iter().enumerate() {
                let color = palette(i);
                let pts = s
                    .points
                    .iter()
                    .copied()
                    .filter(|(x, y)| x.is_finite() && y.is_finite());
                let anno = match s.kind {
                    SeriesKind::Markers => {
                        chart.draw_series(pts.map(|p| Circle::new(p, 5, color.filled())))?
                    }
                    SeriesKind::Line => {
                        chart.draw_series(LineSeries::new(pts, color.stroke_width(2)))?
                    }
                };
                anno.label(s.label.as_str()).legend(move |(x, y)| {
                    Rectangle::new([(x, y - 5), (x + 14, y + 5)], color.filled())
                });
            }
            chart
                .configure_series_labels()
                .background_style(WHITE.mix(0.85))
                .border_style(BLACK)
                .label_font(("sans-serif", 14))
                .position(SeriesLabelPosition::LowerRight)
                .draw()?;
        }};
    }
    if figure.log_x {
        body!(builder.build_cartesian_2d((x0..x1).log_scale(), y0..y1)?);
    } else {
        body!(builder.build_cartesian_2d(x0..x1, y0..y1)?);
    }
    Ok(Ok(()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_png_and_svg_with_the_title_and_labels() {
        let dir = tempfile::tempdir().unwrap();
        let figure = Figure {
            title: "DST front".into(),
            x_label: "time".into(),
            y_label: "treasure".into(),
            series: vec![Series {
                label: "MO-MPO".into(),
                points: vec![(-1.0, 0.7), (-19.0, 23.7)],
                kind: SeriesKind::Markers,
            }],
            log_x: false,
        };
        let files = save(&figure, &dir.path().join("front")).unwrap();
        let png = std::fs::read(&files[0]).unwrap();
        assert_eq!(&png[1..4], b"PNG");
        let svg = std::fs::read_to_string(&files[1]).unwrap();
        for text in ["DST front", "time", "treasure", "MO-MPO"] {
            assert!(svg.contains(text), "svg lacks {text}");
        }
    }

    #[test]
    fn a_figure_without_finite_points_is_an_error() {
        let dir = tempfile::tempdir().unwrap();
        let figure = Figure {
            title: "t".into(),
            x_label: "x".into(),
            y_label: "y".into(),
            series: vec![Series {
                label: "s".into(),
                points: vec![(f64::NAN, 1.0)],
                kind: SeriesKind::Line,
            }],
            log_x: false,
        };
        assert!(matches!(
            save(&figure, &dir.path().join("f")),
            Err(PlotError::Empty(_))
        ));
    }
}
