//! Where a figure's parts go: the axis ranges (finite points, padded), the legend's
//! corner (the one the points leave emptiest), tick labels as a person writes them,
//! and the corners of a step line.

use plotters::prelude::SeriesLabelPosition;

use super::Figure;

/// A figure's axis ranges (its finite points, padded) and where its legend goes.
pub(super) struct Bounds {
    pub(super) x0: f64,
    pub(super) x1: f64,
    pub(super) y0: f64,
    pub(super) y1: f64,
    pub(super) legend: SeriesLabelPosition,
}

impl Bounds {
    /// `None` when the figure has no finite point (none > 0 on a log x axis).
    pub(super) fn of(figure: &Figure) -> Option<Bounds> {
        let finite: Vec<(f64, f64)> = figure
            .series
            .iter()
            .flat_map(|s| s.points.iter().copied())
            .filter(|(x, y)| x.is_finite() && y.is_finite() && (!figure.log_x || *x > 0.0))
            .collect();
        if finite.is_empty() {
            return None;
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
        let legend = emptiest_corner(&finite, (x0, x1), (y0, y1), figure.log_x);
        Some(Bounds {
            x0,
            x1,
            y0,
            y1,
            legend,
        })
    }
}

/// An axis tick as a person writes it: `200k`, `1.5M`, `-19`, `0.25`, `1e-5`.
/// plotters' own labels print every f64 with a decimal point (`200000.0`). Up to three
/// significant decimals are kept, so ticks 0.001 apart stay distinct below 1000.
pub fn tick_label(v: f64) -> String {
    if !v.is_finite() {
        return v.to_string();
    }
    let a = v.abs();
    if a != 0.0 && a < 1e-3 {
        // `{:e}` writes the shortest form: 1e-5, 2.5e-4.
        return format!("{:e}", (v * 1e12).round() / 1e12);
    }
    let (scaled, suffix) = [(1e12, "T"), (1e9, "G"), (1e6, "M"), (1e3, "k")]
        .into_iter()
        .find(|(unit, _)| a >= *unit)
        .map_or((v, ""), |(unit, suffix)| (v / unit, suffix));
    let mut text = format!("{scaled:.3}");
    while text.ends_with('0') {
        text.pop();
    }
    if text.ends_with('.') {
        text.pop();
    }
    if text == "-0" {
        text = "0".into();
    }
    text + suffix
}

/// matplotlib's "tab10" colours: distinct, and readable on white (unlike pure yellow).
/// The legend's corner: the one whose box of about the legend's size (35% of the width,
/// 25% of the height) holds the fewest points, lower right first on ties, so the
/// legend hides as little as it can.
fn emptiest_corner(
    points: &[(f64, f64)],
    (x0, x1): (f64, f64),
    (y0, y1): (f64, f64),
    log_x: bool,
) -> SeriesLabelPosition {
    let fx = |x: f64| {
        if log_x {
            (x.ln() - x0.ln()) / (x1.ln() - x0.ln())
        } else {
            (x - x0) / (x1 - x0)
        }
    };
    let fy = |y: f64| (y - y0) / (y1 - y0);
    let count = |right: bool, top: bool| {
        points
            .iter()
            .filter(|&&(x, y)| {
                let (u, v) = (fx(x), fy(y));
                (if right { u >= 0.65 } else { u <= 0.35 })
                    && (if top { v >= 0.75 } else { v <= 0.25 })
            })
            .count()
    };
    [
        (SeriesLabelPosition::LowerRight, count(true, false)),
        (SeriesLabelPosition::UpperRight, count(true, true)),
        (SeriesLabelPosition::UpperLeft, count(false, true)),
        (SeriesLabelPosition::LowerLeft, count(false, false)),
    ]
    .into_iter()
    .min_by_key(|(_, n)| *n)
    .map(|(corner, _)| corner)
    .unwrap_or(SeriesLabelPosition::LowerRight)
}

/// The corners of a step plot through `points`: horizontal first, then vertical.
pub(super) fn steps(points: &[(f64, f64)]) -> Vec<(f64, f64)> {
    let mut out = Vec::with_capacity(2 * points.len());
    for (i, &p) in points.iter().enumerate() {
        if i > 0 {
            out.push((p.0, points[i - 1].1));
        }
        out.push(p);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ticks_read_like_200k_and_1_5m() {
        let cases = [
            (0.0, "0"),
            (-0.0, "0"),
            (200_000.0, "200k"),
            (1_500_000.0, "1.5M"),
            (1_250_000.0, "1.25M"),
            (12_500.0, "12.5k"),
            (1e9, "1G"),
            (-19.0, "-19"),
            (999.0, "999"),
            (0.25, "0.25"),
            (0.30000000000000004, "0.3"), // a tick that is 3 × 0.1 in f64
            (-2.5, "-2.5"),
            (0.001, "0.001"),
            (0.0005, "5e-4"),
            (1e-5, "1e-5"),
            (f64::INFINITY, "inf"),
        ];
        for (value, text) in cases {
            assert_eq!(tick_label(value), text, "tick {value}");
        }
    }

    #[test]
    fn steps_go_across_then_up_or_down() {
        let corners = steps(&[(0.0, 1.0), (2.0, 3.0), (5.0, 0.5)]);
        assert_eq!(
            corners,
            vec![(0.0, 1.0), (2.0, 1.0), (2.0, 3.0), (5.0, 3.0), (5.0, 0.5)]
        );
    }
}
