//! Pareto-front metrics: non-dominated filter, hypervolume, expected utility, IGD, and
//! the 2-D attainment surface that front plots draw.
//!
//! All objectives are maximised. Points are vector returns `[K]`; a front is a
//! list of them. Definitions follow MORL-Baselines / pymoo (research notes,
//! `morl_anchors.md`): hypervolume of the region dominated by the front and
//! bounded below by a reference point; EUM = mean over weights w of max_i w·v_i;
//! IGD = mean over the true front of the distance to the nearest found point.

/// Indices of the points no other point dominates (duplicates keep their first index).
pub fn non_dominated(points: &[Vec<f64>]) -> Vec<usize> {
    let dominates = |a: &[f64], b: &[f64]| {
        a.iter().zip(b).all(|(x, y)| x >= y) && a.iter().zip(b).any(|(x, y)| x > y)
    };
    (0..points.len())
        .filter(|&i| {
            let p = &points[i];
            !points
                .iter()
                .enumerate()
                .any(|(j, q)| dominates(q, p) || (j < i && q == p))
        })
        .collect()
}

/// Hypervolume dominated by `points` above `reference` (exact; any K).
///
/// Points that do not strictly exceed the reference in every objective add nothing.
/// K = 2 is a sweep over the sorted front; K > 2 slices along the last objective and
/// recurses (fine for the tens of points a sweep produces).
pub fn hypervolume(points: &[Vec<f64>], reference: &[f64]) -> f64 {
    let inside: Vec<Vec<f64>> = points
        .iter()
        .filter(|p| p.iter().zip(reference).all(|(x, r)| x > r))
        .cloned()
        .collect();
    hv_recursive(&inside, reference)
}

fn hv_recursive(points: &[Vec<f64>], reference: &[f64]) -> f64 {
    let k = reference.len();
    if points.is_empty() {
        return 0.0;
    }
    if k == 1 {
        return points
            .iter()
            .map(|p| p[0] - reference[0])
            .fold(0.0, f64::max);
    }
    if k == 2 {
        // Sort by the first objective, best first; each point adds the strip of the
        // second objective above everything seen so far.
        let mut sorted: Vec<&Vec<f64>> = points.iter().collect();
        sorted.sort_by(|a, b| b[0].total_cmp(&a[0]));
        let (mut area, mut best_y) = (0.0, reference[1]);
        for p in sorted {
            if p[1] > best_y {
                area += (p[0] - reference[0]) * (p[1] - best_y);
                best_y = p[1];
            }
        }
        return area;
    }
    // Slice along the last objective: between consecutive levels, the (K-1)-volume
    // of the points reaching at least that level.
    let mut levels: Vec<f64> = points.iter().map(|p| p[k - 1]).collect();
    levels.sort_by(f64::total_cmp);
    levels.dedup();
    let (mut volume, mut below) = (0.0, reference[k - 1]);
    for &level in &levels {
        let reaching: Vec<Vec<f64>> = points
            .iter()
            .filter(|p| p[k - 1] >= level)
            .map(|p| p[..k - 1].to_vec())
            .collect();
        volume += hv_recursive(&reaching, &reference[..k - 1]) * (level - below);
        below = level;
    }
    volume
}

/// Expected utility: mean over `weights` of the best linear utility on the front.
pub fn expected_utility(points: &[Vec<f64>], weights: &[Vec<f64>]) -> f64 {
    let best = |w: &Vec<f64>| {
        points
            .iter()
            .map(|p| p.iter().zip(w).map(|(x, wi)| x * wi).sum::<f64>())
            .fold(f64::NEG_INFINITY, f64::max)
    };
    weights.iter().map(best).sum::<f64>() / weights.len() as f64
}

/// `n` weight vectors spread evenly over the simplex for K = 2 (`[t, 1 - t]`,
/// t = 0..1), or a simplex lattice for K > 2 with at least `n` points.
///
/// MORL-Baselines uses pymoo's Riesz-energy directions for K > 2; for K = 2 both
/// are the evenly spaced line, so two-objective EUM figures are comparable.
pub fn simplex_weights(k: usize, n: usize) -> Vec<Vec<f64>> {
    if k == 2 {
        return (0..n)
            .map(|i| i as f64 / (n - 1).max(1) as f64)
            .map(|t| vec![t, 1.0 - t])
            .collect();
    }
    // Smallest lattice resolution h with C(h + k - 1, k - 1) >= n.
    let count = |h: usize| (1..k).fold(1usize, |acc, i| acc * (h + i) / i);
    let h = (1..).find(|&h| count(h) >= n).expect("finite");
    let mut out = Vec::new();
    let mut current = vec![0usize; k];
    fn fill(i: usize, left: usize, h: usize, current: &mut Vec<usize>, out: &mut Vec<Vec<f64>>) {
        let k = current.len();
        if i == k - 1 {
            current[i] = left;
            out.push(current.iter().map(|&c| c as f64 / h as f64).collect());
            return;
        }
        for c in 0..=left {
            current[i] = c;
            fill(i + 1, left - c, h, current, out);
        }
    }
    fill(0, h, h, &mut current, &mut out);
    out
}

/// The region `points` dominate above `reference`, for K = 2: a closed staircase
/// polygon (the attainment surface), from the reference corner up along the left edge,
/// across every non-dominated point, and down to the reference level. Its area is the
/// hypervolume; drawing it shows exactly the trade-offs some point achieves, where a
/// line joining the points would invent ones between them. Empty when no point
/// exceeds the reference in both objectives.
pub fn attainment_surface(points: &[(f64, f64)], reference: (f64, f64)) -> Vec<(f64, f64)> {
    let (rx, ry) = reference;
    let mut inside: Vec<(f64, f64)> = points
        .iter()
        .copied()
        .filter(|&(x, y)| x > rx && y > ry)
        .collect();
    // Best y first, then best x among equal y: each kept point moves right and down.
    inside.sort_by(|a, b| b.1.total_cmp(&a.1).then(b.0.total_cmp(&a.0)));
    let mut front: Vec<(f64, f64)> = Vec::new();
    for p in inside {
        if front.last().is_none_or(|last| p.0 > last.0) {
            front.push(p);
        }
    }
    let Some(&(_, top)) = front.first() else {
        return Vec::new();
    };
    let mut polygon = vec![(rx, ry), (rx, top)];
    for (i, &(x, y)) in front.iter().enumerate() {
        polygon.push((x, y));
        let next_y = front.get(i + 1).map_or(ry, |n| n.1);
        polygon.push((x, next_y));
    }
    polygon
}

/// Inverted generational distance: mean over `true_front` of the Euclidean distance
/// to the nearest point of `found` (0 when every true point is found).
pub fn igd(found: &[Vec<f64>], true_front: &[Vec<f64>]) -> f64 {
    let dist = |a: &[f64], b: &[f64]| {
        a.iter()
            .zip(b)
            .map(|(x, y)| (x - y).powi(2))
            .sum::<f64>()
            .sqrt()
    };
    true_front
        .iter()
        .map(|t| {
            found
                .iter()
                .map(|f| dist(f, t))
                .fold(f64::INFINITY, f64::min)
        })
        .sum::<f64>()
        / true_front.len() as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Deep Sea Treasure's true front as [time, treasure] (paper B.1 values, shortest
    /// paths of 1, 3, 5, 7, 8, 9, 13, 14, 17, 19 steps).
    fn dst_front() -> Vec<Vec<f64>> {
        [
            (1, 0.7),
            (3, 8.2),
            (5, 11.5),
            (7, 14.0),
            (8, 15.1),
            (9, 16.1),
            (13, 19.6),
            (14, 20.3),
            (17, 22.4),
            (19, 23.7),
        ]
        .iter()
        .map(|&(steps, v)| vec![-f64::from(steps), v])
        .collect()
    }

    #[test]
    fn dst_true_front_hypervolume_is_401_8() {
        // Sorted by time (longest first), each point adds (its time - previous time) x its
        // treasure above the reference (-25, 0):
        // 6*23.7 + 2*22.4 + 3*20.3 + 1*19.6 + 4*16.1 + 1*15.1 + 1*14 + 2*11.5 + 2*8.2 + 2*0.7
        // = 142.2 + 44.8 + 60.9 + 19.6 + 64.4 + 15.1 + 14 + 23 + 16.4 + 1.4 = 401.8
        let hv = hypervolume(&dst_front(), &[-25.0, 0.0]);
        assert!((hv - 401.8).abs() < 1e-9, "{hv}");
    }

    fn shoelace_area(polygon: &[(f64, f64)]) -> f64 {
        let n = polygon.len();
        (0..n)
            .map(|i| {
                let (a, b) = (polygon[i], polygon[(i + 1) % n]);
                a.0 * b.1 - b.0 * a.1
            })
            .sum::<f64>()
            .abs()
            / 2.0
    }

    #[test]
    fn the_attainment_surface_encloses_exactly_the_hypervolume() {
        // Its area (shoelace formula) is the hypervolume, 401.8 for the DST front, also
        // with dominated, duplicate and below-reference points mixed in.
        let mut points: Vec<(f64, f64)> = dst_front().iter().map(|p| (p[0], p[1])).collect();
        points.extend([(-10.0, 10.0), (-1.0, 0.7), (-30.0, 5.0), (-2.0, -1.0)]);
        let polygon = attainment_surface(&points, (-25.0, 0.0));
        assert!((shoelace_area(&polygon) - 401.8).abs() < 1e-9);
        // A staircase: every edge is horizontal or vertical, starting at the reference.
        assert_eq!(polygon[0], (-25.0, 0.0));
        assert_eq!(polygon[1], (-25.0, 23.7));
        assert_eq!(polygon[2], (-19.0, 23.7));
        assert_eq!(polygon[3], (-19.0, 22.4));
        assert_eq!(*polygon.last().unwrap(), (-1.0, 0.0));
        let n = polygon.len();
        assert!((0..n).all(|i| {
            let (a, b) = (polygon[i], polygon[(i + 1) % n]);
            a.0 == b.0 || a.1 == b.1
        }));
        assert!(attainment_surface(&[(-30.0, 5.0)], (-25.0, 0.0)).is_empty());
    }

    #[test]
    fn missing_a_treasure_loses_exactly_its_strip() {
        // Without (−8, 15.1) the strip (−8 − (−9)) x (15.1 − 14.0) = 1.1 is no longer covered.
        let mut front = dst_front();
        front.remove(4);
        assert!((hypervolume(&front, &[-25.0, 0.0]) - (401.8 - 1.1)).abs() < 1e-9);
    }

    #[test]
    fn dominated_and_duplicate_points_are_filtered_and_add_no_volume() {
        let mut points = dst_front();
        points.push(vec![-10.0, 10.0]); // dominated by (−9, 16.1)
        points.push(vec![-1.0, 0.7]); // duplicate of the first point
        let keep = non_dominated(&points);
        assert_eq!(keep, (0..10).collect::<Vec<_>>());
        assert!((hypervolume(&points, &[-25.0, 0.0]) - 401.8).abs() < 1e-9);
    }

    #[test]
    fn three_objective_hypervolume_of_boxes() {
        // Union of [0,2]x[0,1]x[0,1] and [0,1]x[0,2]x[0,2]: 2 + 4 - overlap 1x1x1 = 5.
        let hv = hypervolume(
            &[vec![2.0, 1.0, 1.0], vec![1.0, 2.0, 2.0]],
            &[0.0, 0.0, 0.0],
        );
        assert!((hv - 5.0).abs() < 1e-12, "{hv}");
    }

    #[test]
    fn expected_utility_and_igd_on_a_two_point_front() {
        let front = vec![vec![1.0, 0.0], vec![0.0, 1.0]];
        // Weights (0,1), (0.5,0.5), (1,0): best utilities 1, 0.5, 1 -> mean 5/6.
        let eum = expected_utility(&front, &simplex_weights(2, 3));
        assert!((eum - 5.0 / 6.0).abs() < 1e-12);
        assert_eq!(igd(&front, &front), 0.0);
        // Only (1,0) found: distances 0 and sqrt(2) -> mean sqrt(2)/2.
        assert!((igd(&front[..1], &front) - 2f64.sqrt() / 2.0).abs() < 1e-12);
    }

    #[test]
    fn simplex_lattice_weights_sum_to_one() {
        let w = simplex_weights(3, 10);
        assert!(w.len() >= 10);
        assert!(
            w.iter()
                .all(|v| (v.iter().sum::<f64>() - 1.0).abs() < 1e-12)
        );
    }
}
