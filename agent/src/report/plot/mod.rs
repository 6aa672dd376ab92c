//! Figures for fronts and learning curves, written as PNG and SVG with plotters.
//!
//! The font is embedded (DejaVu Sans, `agent/assets/`), so rendering needs no
//! system font libraries.

use std::path::{Path, PathBuf};

use plotters::coord::Shift;
use plotters::prelude::*;

mod layout;

pub use layout::tick_label;
use layout::{Bounds, steps};

/// How a series is drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SeriesKind {
    /// Unconnected filled circles (sweep points).
    Markers,
    /// Unconnected hollow circles (a known optimum, e.g. the true front).
    OpenMarkers,
    /// Crosses (a reference point).
    Crosses,
    /// A polyline (learning curves).
    Line,
    /// A step plot: from each point horizontally to the next x, then vertically.
    Steps,
    /// A closed polygon, lightly filled and outlined (a dominated region).
    Region,
    /// A thin horizontal line across the plot at each point's y (levels to read off).
    Levels,
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

/// Write `<stem>.png` and `<stem>.svg`; returns both paths.
pub fn save(figure: &Figure, stem: &Path) -> Result<Vec<PathBuf>, PlotError> {
    crate::report::font::register();
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
    let Some(b) = Bounds::of(figure) else {
        return Ok(Err(PlotError::Empty(path.to_path_buf())));
    };
    root.fill(&WHITE)?;
    let mut builder = ChartBuilder::on(root);
    builder
        .caption(&figure.title, ("sans-serif", 24))
        .margin(16)
        .x_label_area_size(48)
        .y_label_area_size(64);
    // One body for both x axes: a log and a linear chart are different types.
    macro_rules! body {
        ($chart:expr) => {{
            let mut chart = $chart;
            chart
                .configure_mesh()
                .x_desc(figure.x_label.as_str())
                .y_desc(figure.y_label.as_str())
                .x_label_formatter(&|x| tick_label(*x))
                .y_label_formatter(&|y| tick_label(*y))
                .label_style(("sans-serif", 14))
                .draw()?;
            for (i, s) in figure.series.iter().enumerate() {
                let (r, g, bl) = TAB10[i % TAB10.len()];
                draw_series(&mut chart, s, RGBColor(r, g, bl).to_rgba(), (b.x0, b.x1))?;
            }
            chart
                .configure_series_labels()
                .background_style(WHITE.mix(0.85))
                .border_style(BLACK)
                .label_font(("sans-serif", 14))
                .position(b.legend.clone())
                .draw()?;
        }};
    }
    if figure.log_x {
        body!(builder.build_cartesian_2d((b.x0..b.x1).log_scale(), b.y0..b.y1)?);
    } else {
        body!(builder.build_cartesian_2d(b.x0..b.x1, b.y0..b.y1)?);
    }
    Ok(Ok(()))
}

/// Draws one series in its kind's style, with its legend entry; `x_range` is the axis's
/// (a `Levels` line spans it).
fn draw_series<DB, CT>(
    chart: &mut ChartContext<'_, DB, CT>,
    s: &Series,
    color: RGBAColor,
    x_range: (f64, f64),
) -> Result<(), Box<dyn std::error::Error>>
where
    DB: DrawingBackend,
    DB::ErrorType: 'static,
    CT: CoordTranslate<From = (f64, f64)>,
{
    let pts = s
        .points
        .iter()
        .copied()
        .filter(|(x, y)| x.is_finite() && y.is_finite());
    let anno = match s.kind {
        SeriesKind::Markers => chart.draw_series(pts.map(|p| Circle::new(p, 5, color.filled())))?,
        SeriesKind::OpenMarkers => {
            chart.draw_series(pts.map(|p| Circle::new(p, 8, color.stroke_width(2))))?
        }
        SeriesKind::Crosses => {
            chart.draw_series(pts.map(|p| Cross::new(p, 7, color.stroke_width(3))))?
        }
        SeriesKind::Line => chart.draw_series(LineSeries::new(pts, color.stroke_width(2)))?,
        SeriesKind::Steps => {
            let corners: Vec<(f64, f64)> = pts.collect();
            chart.draw_series(corners.iter().map(|&p| Circle::new(p, 4, color.filled())))?;
            chart.draw_series(LineSeries::new(steps(&corners), color.stroke_width(2)))?
        }
        SeriesKind::Region => {
            let ring: Vec<(f64, f64)> = pts.collect();
            let mut outline = ring.clone();
            outline.extend(ring.first().copied());
            chart.draw_series([Polygon::new(ring, color.mix(0.18).filled())])?;
            chart.draw_series(LineSeries::new(outline, color.stroke_width(2)))?
        }
        SeriesKind::Levels => {
            let (lo, hi) = x_range;
            let style = color.mix(0.6).stroke_width(1);
            chart.draw_series(pts.map(|(_, y)| PathElement::new(vec![(lo, y), (hi, y)], style)))?
        }
    };
    anno.label(s.label.as_str())
        .legend(move |(x, y)| Rectangle::new([(x, y - 5), (x + 14, y + 5)], color.filled()));
    Ok(())
}

const TAB10: [(u8, u8, u8); 10] = [
    (31, 119, 180),
    (255, 127, 14),
    (44, 160, 44),
    (214, 39, 40),
    (148, 103, 189),
    (140, 86, 75),
    (227, 119, 194),
    (127, 127, 127),
    (188, 189, 34),
    (23, 190, 207),
];

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
    fn drawn_ticks_are_the_short_labels() {
        let dir = tempfile::tempdir().unwrap();
        let figure = Figure {
            title: "t".into(),
            x_label: "env steps".into(),
            y_label: "return".into(),
            series: vec![Series {
                label: "s".into(),
                points: vec![(0.0, 0.0), (2_000_000.0, 1.0)],
                kind: SeriesKind::Line,
            }],
            log_x: false,
        };
        let files = save(&figure, &dir.path().join("f")).unwrap();
        let svg = std::fs::read_to_string(&files[1]).unwrap();
        assert!(svg.contains("\n1M\n"), "no 1M tick: {svg}");
        assert!(!svg.contains("00000\n"), "a long tick label is left: {svg}");
    }

    #[test]
    fn every_series_kind_draws_with_its_legend() {
        let dir = tempfile::tempdir().unwrap();
        let kinds = [
            SeriesKind::Markers,
            SeriesKind::OpenMarkers,
            SeriesKind::Crosses,
            SeriesKind::Line,
            SeriesKind::Steps,
            SeriesKind::Region,
            SeriesKind::Levels,
        ];
        let figure = Figure {
            title: "kinds".into(),
            x_label: "x".into(),
            y_label: "y".into(),
            series: kinds
                .iter()
                .enumerate()
                .map(|(i, &kind)| Series {
                    label: format!("kind{i}"),
                    points: vec![(1.0, i as f64), (2.0, i as f64 + 1.0), (3.0, 0.5)],
                    kind,
                })
                .collect(),
            log_x: true,
        };
        let files = save(&figure, &dir.path().join("kinds")).unwrap();
        let svg = std::fs::read_to_string(&files[1]).unwrap();
        for i in 0..kinds.len() {
            assert!(svg.contains(&format!("kind{i}")), "svg lacks kind{i}");
        }
        assert!(svg.contains("<polygon"), "the region is a filled polygon");
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
