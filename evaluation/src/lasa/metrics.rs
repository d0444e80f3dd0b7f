//! Imitation metrics of the LASA benchmark, between a reproduction `ŷ` and the
//! demonstration `y` it starts from (both planar, sampled at the same period).

/// A planar point, mm.
pub type Point = [f64; 2];

fn finite(path: &[Point]) -> bool {
    path.iter().flatten().all(|v| v.is_finite())
}

fn distance(a: &Point, b: &Point) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

/// Dynamic-time-warping distance per aligned sample (mm):
///
/// `DTW(ŷ, y) / max(|ŷ|, |y|)`, `DTW = D(|ŷ|, |y|)`,
/// `D(i, j) = ‖ŷ_i − y_j‖ + min(D(i−1, j), D(i, j−1), D(i−1, j−1))`,
///
/// the cumulative Euclidean cost of the best monotone alignment, divided by the longer
/// path's length so shapes of different lengths compare. Infinite when either path is
/// empty or holds a non-finite point.
pub fn dtw_distance(reproduction: &[Point], demonstration: &[Point]) -> f64 {
    if reproduction.is_empty() || demonstration.is_empty() {
        return f64::INFINITY;
    }
    if !(finite(reproduction) && finite(demonstration)) {
        return f64::INFINITY;
    }
    let m = demonstration.len();
    let mut previous = vec![f64::INFINITY; m + 1];
    let mut current = vec![f64::INFINITY; m + 1];
    previous[0] = 0.0;
    for p in reproduction {
        current[0] = f64::INFINITY;
        for (j, q) in demonstration.iter().enumerate() {
            let best = previous[j].min(previous[j + 1]).min(current[j]);
            current[j + 1] = distance(p, q) + best;
        }
        std::mem::swap(&mut previous, &mut current);
    }
    previous[m] / m.max(reproduction.len()) as f64
}

/// Swept error area (mm²), as in Khansari-Zadeh & Billard (2014): the sum over time of the
/// areas of the quadrilaterals `(y_t, y_{t+1}, ŷ_{t+1}, ŷ_t)` spanned by consecutive points
/// of the demonstration and of the time-aligned reproduction,
///
/// `SEA = Σ_t A(y_t, y_{t+1}, ŷ_{t+1}, ŷ_t)`,
///
/// `A` the area the quadrilateral encloses ([`quadrilateral_area`]: where the paths cross
/// within a step, both lobes of the bow tie count).
///
/// Compares the first `min(|ŷ|, |y|)` samples; infinite for a non-finite point.
pub fn swept_error_area(reproduction: &[Point], demonstration: &[Point]) -> f64 {
    if !(finite(reproduction) && finite(demonstration)) {
        return f64::INFINITY;
    }
    demonstration
        .windows(2)
        .zip(reproduction.windows(2))
        .map(|(y, r)| quadrilateral_area([y[0], y[1], r[1], r[0]]))
        .sum()
}

/// The area enclosed by the quadrilateral `p_0 p_1 p_2 p_3`. A simple one's is the shoelace
/// formula's; a self-intersecting one (a bow tie: opposite sides cross at `X`) encloses
/// two triangles, whose areas add, where the shoelace formula would subtract them.
fn quadrilateral_area(p: [Point; 4]) -> f64 {
    if let Some(x) = crossing([p[0], p[1]], [p[2], p[3]]) {
        triangle_area([p[0], x, p[3]]) + triangle_area([x, p[1], p[2]])
    } else if let Some(x) = crossing([p[1], p[2]], [p[3], p[0]]) {
        triangle_area([p[0], p[1], x]) + triangle_area([x, p[2], p[3]])
    } else {
        shoelace(&p)
    }
}

/// `(b − a) × (c − a)`: twice the signed area of the triangle `a b c`.
fn cross(a: Point, b: Point, c: Point) -> f64 {
    (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
}

fn triangle_area([a, b, c]: [Point; 3]) -> f64 {
    0.5 * cross(a, b, c).abs()
}

/// The point where the segments `a` and `b` cross, each strictly between its ends (a
/// touch at an end point leaves the quadrilateral simple).
fn crossing(a: [Point; 2], b: [Point; 2]) -> Option<Point> {
    let (a0, a1) = (cross(b[0], b[1], a[0]), cross(b[0], b[1], a[1]));
    let (b0, b1) = (cross(a[0], a[1], b[0]), cross(a[0], a[1], b[1]));
    if a0 * a1 >= 0.0 || b0 * b1 >= 0.0 {
        return None;
    }
    let t = a0 / (a0 - a1);
    Some([
        a[0][0] + t * (a[1][0] - a[0][0]),
        a[0][1] + t * (a[1][1] - a[0][1]),
    ])
}

/// `|½ Σ_i (x_i y_{i+1} − x_{i+1} y_i)|`, the area of a simple polygon.
fn shoelace(polygon: &[Point]) -> f64 {
    let n = polygon.len();
    let twice: f64 = (0..n)
        .map(|i| {
            let (a, b) = (polygon[i], polygon[(i + 1) % n]);
            a[0] * b[1] - b[0] * a[1]
        })
        .sum();
    0.5 * twice.abs()
}

/// `‖ŷ_T − y_T‖` (mm): the reproduction's last point against the demonstration's.
pub fn final_point_error(reproduction: &[Point], demonstration: &[Point]) -> f64 {
    match (reproduction.last(), demonstration.last()) {
        (Some(r), Some(y)) if finite(&[*r, *y]) => distance(r, y),
        _ => f64::INFINITY,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn line(n: usize, offset: f64) -> Vec<Point> {
        (0..n).map(|i| [i as f64, offset]).collect()
    }

    #[test]
    fn identical_paths_score_zero() {
        let path: Vec<Point> = (0..50).map(|i| [(i as f64).sin(), i as f64]).collect();
        assert_eq!(dtw_distance(&path, &path), 0.0);
        assert_eq!(swept_error_area(&path, &path), 0.0);
        assert_eq!(final_point_error(&path, &path), 0.0);
    }

    #[test]
    fn parallel_lines_sweep_their_rectangle() {
        let (demo, shifted) = (line(11, 0.0), line(11, 2.0));
        // A 10 × 2 rectangle; every sample is 2 mm from its partner.
        assert!((swept_error_area(&shifted, &demo) - 20.0).abs() < 1e-12);
        assert!((dtw_distance(&shifted, &demo) - 2.0).abs() < 1e-12);
        assert!((final_point_error(&shifted, &demo) - 2.0).abs() < 1e-12);
    }

    #[test]
    fn paths_that_cross_within_a_step_sweep_both_lobes() {
        // The reproduction falls from y = 1 to y = −1 across the demonstration's y = 0,
        // crossing it halfway through the step from x = 4 to x = 5: two triangles of base
        // 4.5 and height 1.
        let demo = line(10, 0.0);
        let falling: Vec<Point> = (0..10)
            .map(|i| [i as f64, 1.0 - 2.0 * i as f64 / 9.0])
            .collect();
        assert!((swept_error_area(&falling, &demo) - 4.5).abs() < 1e-12);
        // Time-aligned pairs that cross each other: the reproduction runs the step backwards.
        let demo = [[0.0, 0.0], [1.0, 0.0]];
        let backwards = [[1.0, 1.0], [0.0, 1.0]];
        assert!((swept_error_area(&backwards, &demo) - 0.5).abs() < 1e-12);
        // Touching at a sample is no crossing: the two lobes are triangles of their own steps.
        let demo = line(3, 0.0);
        let touching = [[0.0, 1.0], [1.0, 0.0], [2.0, 1.0]];
        assert!((swept_error_area(&touching, &demo) - 1.0).abs() < 1e-12);
    }

    #[test]
    fn dtw_forgives_timing_but_the_final_point_error_does_not() {
        let demo = line(21, 0.0);
        // The same path, lingering at its start: DTW aligns it, the time-aligned end lags.
        let mut slow = vec![[0.0, 0.0]; 5];
        slow.extend(line(21, 0.0));
        assert_eq!(dtw_distance(&slow, &demo), 0.0);
        assert!(final_point_error(&slow[..21], &demo) > 4.0);
    }

    #[test]
    fn non_finite_or_empty_paths_score_infinity() {
        let demo = line(5, 0.0);
        let mut broken = line(5, 1.0);
        broken[3] = [f64::NAN, 0.0];
        assert_eq!(dtw_distance(&broken, &demo), f64::INFINITY);
        assert_eq!(swept_error_area(&broken, &demo), f64::INFINITY);
        assert_eq!(dtw_distance(&[], &demo), f64::INFINITY);
        assert_eq!(final_point_error(&[], &demo), f64::INFINITY);
        broken[4] = [f64::INFINITY, 0.0];
        assert_eq!(final_point_error(&broken, &demo), f64::INFINITY);
    }
}
