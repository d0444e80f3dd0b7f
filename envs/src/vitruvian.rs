//! The "Vitruvian man" outlines of the limit-cycle task.
//!
//! For phases `c ∈ [0, 1]` each outline is a star-shaped closed curve in polar form
//! around the origin,
//!
//! `r(θ, c) = r₀ + Σₖ hₖ exp(κₖ (cos(θ − θₖ(c)) − 1))`,
//!
//! a circle (the torso) with von Mises bumps for the head, the two arms and the two legs.
//! Since `r > 0` everywhere the curve is simple and closed, so a stable limit cycle can
//! trace it. The phase moves the limbs smoothly: the arms rise from slightly below
//! horizontal (`c = 0`) to raised (`c = 1`), the legs spread apart.
//!
//! For `c ∈ [1, 2]` the figure of phase 1 *curls*: its points are turned about the centre
//! by an angle growing with the square of their distance,
//!
//! `T(x) = R(κ |x|²) x`,  `κ = CURL · (c − 1)`,
//!
//! so the limbs bend into hooks. `T` is a diffeomorphism of the plane (it keeps `|x|` and
//! shifts the polar angle smoothly), so the curled outline is still a simple closed curve;
//! from `c ≈ 1.15` on it is no longer star-shaped about the centre (some ray from it
//! crosses the outline three times, from `c ≈ 1.8` five), so no polar radius describes it.

use std::collections::HashMap;
use std::f64::consts::{FRAC_PI_2, PI};
use std::sync::{Arc, Mutex, OnceLock, Weak};

use nalgebra::Vector2;

/// Torso radius `r₀` in metres.
pub const TORSO_RADIUS: f64 = 0.3;
/// Curl rate at `c = 2`, rad/m²: the arm tips (0.85 m out) turn 2.2 rad, the shoulders
/// (0.3 m) 0.27 rad.
pub const CURL: f64 = 3.0;
/// Points of the polyline [`Outline::distance`] measures against…
const DISTANCE_POINTS: usize = 2000;
/// …in runs of this many segments, each bounded by a disc so that most are skipped.
const RUN: usize = 40;
const RUNS: usize = DISTANCE_POINTS / RUN;

/// One limb: a von Mises bump `h exp(κ (cos(θ − θₖ) − 1))` on the torso circle.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Bump {
    /// Polar angle of the limb's tip, rad.
    angle: f64,
    /// Extra radius at the tip, m.
    height: f64,
    /// Concentration; the bump's angular half-width is about `1/√κ` rad.
    concentration: f64,
}

impl Bump {
    fn value(&self, theta: f64) -> f64 {
        self.height * (self.concentration * ((theta - self.angle).cos() - 1.0)).exp()
    }

    fn derivative(&self, theta: f64) -> f64 {
        -self.concentration * (theta - self.angle).sin() * self.value(theta)
    }
}

/// The outline for one context `c` (module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct Outline {
    bumps: [Bump; 5],
    /// `κ` of the curl `T`, rad/m² (0 for the star-shaped phases).
    curl: f64,
    /// Dense points of the curve, for distances to it, closed: the first point is
    /// repeated at the end, so segment `i` joins point `i` to point `i + 1`.
    points: Vec<Vector2<f64>>,
    /// `1 / |chord|²` of each segment (0 for a chord of length 0): a product per query
    /// instead of a division.
    inverse_lengths_squared: Vec<f64>,
    /// Per run of `RUN` segments: a disc holding them.
    runs: RunDiscs,
}

/// The discs holding the runs of segments, each coordinate in an array of its own so that
/// the distances to all of them are taken several at a time.
#[derive(Clone, Debug, PartialEq)]
struct RunDiscs {
    centre_x: [f64; RUNS],
    centre_y: [f64; RUNS],
    radius: [f64; RUNS],
}

/// Squared distance from `x` to the segment `[a, b]`, whose `1 / |b − a|²` is
/// `inverse_length_squared`: to the projection of `x` onto the chord, clamped to its ends.
#[inline(always)]
fn segment_distance_squared(
    x: &Vector2<f64>,
    a: &Vector2<f64>,
    b: &Vector2<f64>,
    inverse_length_squared: f64,
) -> f64 {
    let (offset, chord) = (x - a, b - a);
    let along = (offset.dot(&chord) * inverse_length_squared).clamp(0.0, 1.0);
    (offset - along * chord).norm_squared()
}

/// `1 / |b − a|²`, or 0 when `a = b` (the projection is then `a` itself).
fn inverse_length_squared(a: &Vector2<f64>, b: &Vector2<f64>) -> f64 {
    let length_squared = (b - a).norm_squared();
    if length_squared > 0.0 {
        1.0 / length_squared
    } else {
        0.0
    }
}

impl Outline {
    /// The outline at `c`, shared with every holder of the same context in this process.
    /// An outline holds `DISTANCE_POINTS` dense points and their chords' inverse lengths (48 kB) and takes a few hundred
    /// microseconds to build: a batch of environments on the task's few scheduled
    /// contexts would otherwise hold a copy each and rebuild it on every reset.
    pub fn shared(c: f64) -> Arc<Outline> {
        static CACHE: OnceLock<Mutex<HashMap<u64, Weak<Outline>>>> = OnceLock::new();
        let mut cache = CACHE
            .get_or_init(Mutex::default)
            .lock()
            .unwrap_or_else(|p| p.into_inner());
        if let Some(outline) = cache.get(&c.to_bits()).and_then(Weak::upgrade) {
            return outline;
        }
        // Continuous contexts leave dead entries behind: sweep them now and then.
        if cache.len() >= 1024 {
            cache.retain(|_, outline| outline.strong_count() > 0);
        }
        let outline = Arc::new(Outline::new(c));
        cache.insert(c.to_bits(), Arc::downgrade(&outline));
        outline
    }

    /// The outline at `c`; `c` outside `[0, 2]` extrapolates the same formulas.
    pub fn new(c: f64) -> Self {
        let phase = c.min(1.0);
        // Arm elevation above horizontal and leg spread from vertical, rad.
        let arm = -0.1 + 0.7 * phase;
        let leg = 0.25 + 0.35 * phase;
        let arm_bump = |angle| Bump {
            angle,
            height: 0.55,
            concentration: 40.0,
        };
        let leg_bump = |angle| Bump {
            angle,
            height: 0.6,
            concentration: 30.0,
        };
        let mut outline = Self {
            bumps: [
                Bump {
                    angle: FRAC_PI_2,
                    height: 0.25,
                    concentration: 20.0,
                },
                arm_bump(arm),
                arm_bump(PI - arm),
                leg_bump(-FRAC_PI_2 - leg),
                leg_bump(-FRAC_PI_2 + leg),
            ],
            curl: CURL * (c - 1.0).max(0.0),
            points: Vec::new(),
            inverse_lengths_squared: Vec::new(),
            runs: RunDiscs {
                centre_x: [0.0; RUNS],
                centre_y: [0.0; RUNS],
                radius: [0.0; RUNS],
            },
        };
        outline.points = outline.polyline(DISTANCE_POINTS);
        // Closed: the first point again at the end, so runs index without wrapping.
        outline.points.push(outline.points[0]);
        outline.inverse_lengths_squared = (outline.points.windows(2))
            .map(|ab| inverse_length_squared(&ab[0], &ab[1]))
            .collect();
        for k in 0..RUNS {
            let ends = outline.run_points(k);
            let centre = ends.iter().sum::<Vector2<f64>>() / ends.len() as f64;
            let radius = ends.iter().map(|p| (p - centre).norm()).fold(0.0, f64::max);
            let runs = &mut outline.runs;
            (runs.centre_x[k], runs.centre_y[k], runs.radius[k]) = (centre.x, centre.y, radius);
        }
        outline
    }

    /// The `RUN + 1` polyline points of run `k` (its segments' ends; the last run's
    /// closes the curve).
    fn run_points(&self, k: usize) -> &[Vector2<f64>] {
        &self.points[k * RUN..=(k + 1) * RUN]
    }

    /// The star-shaped figure's radius `r(θ)` before the curl, m.
    pub fn radius(&self, theta: f64) -> f64 {
        TORSO_RADIUS + self.bumps.iter().map(|b| b.value(theta)).sum::<f64>()
    }

    /// `∂r/∂θ`, m/rad.
    pub fn radius_derivative(&self, theta: f64) -> f64 {
        self.bumps.iter().map(|b| b.derivative(theta)).sum()
    }

    /// `κ` of the curl, rad/m².
    pub fn curl(&self) -> f64 {
        self.curl
    }

    /// `T(x)`: `x` turned by `κ |x|²`.
    pub fn curled(&self, x: &Vector2<f64>) -> Vector2<f64> {
        rotate(x, self.curl * x.norm_squared())
    }

    /// `T⁻¹(x)`: `T` keeps `|x|`, so the inverse turns back by the same angle.
    pub fn uncurled(&self, x: &Vector2<f64>) -> Vector2<f64> {
        rotate(x, -self.curl * x.norm_squared())
    }

    /// `∂T/∂x · v` at `x`: `R(φ) (v + 2κ (x·v) J x)`, `φ = κ|x|²`, `J` the quarter turn.
    pub fn curl_tangent(&self, x: &Vector2<f64>, v: &Vector2<f64>) -> Vector2<f64> {
        let quarter_turn = Vector2::new(-x.y, x.x);
        let turned = v + 2.0 * self.curl * x.dot(v) * quarter_turn;
        rotate(&turned, self.curl * x.norm_squared())
    }

    /// The point of the outline whose star-shaped preimage is at polar angle `θ`.
    pub fn point(&self, theta: f64) -> Vector2<f64> {
        self.curled(&(self.radius(theta) * Vector2::new(theta.cos(), theta.sin())))
    }

    /// `n` points evenly spaced in the preimage's `θ`, counter-clockwise from `θ = 0`.
    pub fn polyline(&self, n: usize) -> Vec<Vector2<f64>> {
        (0..n)
            .map(|i| self.point(2.0 * PI * i as f64 / n as f64))
            .collect()
    }

    /// Euclidean distance from `x` to the outline, m (to a polyline of
    /// `DISTANCE_POINTS` points whose chords stray from the curve by under 0.1 mm). Exact
    /// for that polyline: a run is skipped only when its disc is farther than the nearest
    /// segment found so far, starting from the run whose disc is nearest.
    pub fn distance(&self, x: &Vector2<f64>) -> f64 {
        // How far `x` is from each run's disc: no segment of the run is nearer.
        let mut bounds = [0.0; RUNS];
        let runs = &self.runs;
        let discs = (runs.centre_x.iter().zip(&runs.centre_y)).zip(&runs.radius);
        for (bound, ((centre_x, centre_y), radius)) in bounds.iter_mut().zip(discs) {
            let (dx, dy) = (x.x - centre_x, x.y - centre_y);
            *bound = (dx * dx + dy * dy).sqrt() - radius;
        }
        // The nearest squared distance, whose square root is the nearest distance (the
        // square root is monotonic and correctly rounded): one square root per run read.
        let run_distance_squared = |k: usize| {
            let inverse_lengths_squared = &self.inverse_lengths_squared[k * RUN..(k + 1) * RUN];
            (self.run_points(k).windows(2).zip(inverse_lengths_squared))
                .map(|(ab, &inverse)| segment_distance_squared(x, &ab[0], &ab[1], inverse))
                .fold(f64::INFINITY, f64::min)
        };
        let nearest = (0..RUNS)
            .min_by(|&a, &b| bounds[a].total_cmp(&bounds[b]))
            .expect("an outline has runs");
        let mut best_squared = run_distance_squared(nearest);
        let mut best = best_squared.sqrt();
        for (k, bound) in bounds.iter().enumerate() {
            if k != nearest && *bound < best {
                let squared = run_distance_squared(k);
                if squared < best_squared {
                    (best_squared, best) = (squared, squared.sqrt());
                }
            }
        }
        best
    }
}

/// `x` turned counter-clockwise by `angle`.
fn rotate(x: &Vector2<f64>, angle: f64) -> Vector2<f64> {
    let (sin, cos) = angle.sin_cos();
    Vector2::new(cos * x.x - sin * x.y, sin * x.x + cos * x.y)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shared_outlines_are_one_per_context_and_equal_to_a_fresh_one() {
        let a = Outline::shared(1.2345);
        let b = Outline::shared(1.2345);
        assert!(Arc::ptr_eq(&a, &b), "one outline per context");
        assert_eq!(*a, Outline::new(1.2345));
        assert!(!Arc::ptr_eq(&a, &Outline::shared(1.5432)));
        // Once every holder let go, the context is built afresh.
        let weak = Arc::downgrade(&a);
        drop((a, b));
        assert!(weak.upgrade().is_none());
        assert_eq!(*Outline::shared(1.2345), Outline::new(1.2345));
    }

    #[test]
    fn radius_derivative_matches_finite_differences() {
        let outline = Outline::new(0.37);
        for i in 0..64 {
            let theta = -PI + 2.0 * PI * i as f64 / 64.0;
            let h = 1e-6;
            let numeric = (outline.radius(theta + h) - outline.radius(theta - h)) / (2.0 * h);
            assert!((numeric - outline.radius_derivative(theta)).abs() < 1e-5);
        }
    }

    #[test]
    fn outlines_vary_continuously_with_the_context() {
        for i in 0..=40 {
            let c = i as f64 / 20.0;
            let (a, b) = (Outline::new(c), Outline::new(c + 1e-4));
            for j in 0..360 {
                let theta = (j as f64).to_radians();
                assert!(a.radius(theta) >= TORSO_RADIUS);
                assert!((a.point(theta) - b.point(theta)).norm() < 1e-3, "c = {c}");
            }
        }
    }

    /// The most points in which one ray from the centre crosses the outline of `c`
    /// (rays at angles off the polyline's vertices, so no crossing is counted twice).
    fn most_ray_crossings(c: f64) -> usize {
        let points = Outline::new(c).polyline(4000);
        (0..997)
            .map(|k| {
                let angle = 2.0 * PI * (k as f64 + 0.37) / 997.0;
                let direction = Vector2::new(angle.cos(), angle.sin());
                let next = points.iter().cycle().skip(1);
                points
                    .iter()
                    .zip(next)
                    .filter(|(a, b)| {
                        let side = |p: &Vector2<f64>| direction.perp(p);
                        side(a).signum() != side(b).signum()
                            && a.dot(&direction) > 0.0
                            && b.dot(&direction) > 0.0
                    })
                    .count()
            })
            .max()
            .unwrap()
    }

    #[test]
    fn phases_are_star_shaped_and_curled_outlines_are_not() {
        for c in [0.0, 0.5, 1.0, 1.1] {
            assert_eq!(most_ray_crossings(c), 1, "c = {c}");
        }
        for c in [1.2, 1.5] {
            assert_eq!(most_ray_crossings(c), 3, "c = {c}");
        }
        assert_eq!(most_ray_crossings(2.0), 5);
    }

    #[test]
    fn the_curl_is_inverted_and_differentiated_correctly() {
        let outline = Outline::new(1.8);
        let h = 1e-6;
        for i in 0..50 {
            let x = Vector2::new(-1.0 + 0.04 * i as f64, 0.7 - 0.03 * i as f64);
            assert!((outline.uncurled(&outline.curled(&x)) - x).norm() < 1e-14);
            let v = Vector2::new(0.3, -0.8);
            let numeric = (outline.curled(&(x + h * v)) - outline.curled(&(x - h * v))) / (2.0 * h);
            assert!((numeric - outline.curl_tangent(&x, &v)).norm() < 1e-7);
        }
    }

    #[test]
    fn distance_equals_the_nearest_of_all_segments() {
        for c in [0.3, 1.9] {
            let outline = Outline::new(c);
            assert_eq!(outline.points.len(), DISTANCE_POINTS + 1);
            for i in 0..400 {
                let x = Vector2::new(-1.3 + 0.0065 * i as f64, 1.1 - 0.0057 * i as f64);
                let brute = (outline
                    .points
                    .windows(2)
                    .zip(&outline.inverse_lengths_squared))
                // One square root per segment, the nearest kept.
                .map(|(ab, &inverse)| segment_distance_squared(&x, &ab[0], &ab[1], inverse).sqrt())
                .fold(f64::INFINITY, f64::min);
                assert_eq!(outline.distance(&x), brute, "c = {c}, {x:?}");
            }
        }
    }

    /// The projection with the chord's inverse length against the textbook one, which
    /// divides: on, before, beside and past a chord, and on one of length 0.
    #[test]
    fn a_segment_measures_the_distance_to_its_nearest_point() {
        let (a, b) = (Vector2::new(0.2, -0.1), Vector2::new(0.5, 0.3));
        let textbook = |x: &Vector2<f64>| {
            let t = ((x - a).dot(&(b - a)) / (b - a).norm_squared()).clamp(0.0, 1.0);
            (x - (a + t * (b - a))).norm()
        };
        let inverse = inverse_length_squared(&a, &b);
        for x in [
            a,
            b,
            (a + b) / 2.0,
            Vector2::new(-1.0, 0.4),
            Vector2::new(2.0, 2.0),
            Vector2::new(0.0, 0.6),
        ] {
            let error = (segment_distance_squared(&x, &a, &b, inverse).sqrt() - textbook(&x)).abs();
            assert!(
                error <= 1e-15 * (1.0 + textbook(&x)),
                "{x:?}: off by {error}"
            );
        }
        let degenerate = inverse_length_squared(&a, &a);
        assert_eq!(degenerate, 0.0);
        assert_eq!(
            segment_distance_squared(&b, &a, &a, degenerate),
            (b - a).norm_squared()
        );
    }

    #[test]
    fn distance_is_zero_on_the_curve_and_the_offset_off_it() {
        let outline = Outline::new(2.0);
        for i in 0..90 {
            let theta = (4.0 * i as f64 + 0.5).to_radians();
            let p = outline.point(theta);
            assert!(outline.distance(&p) < 1e-4, "{theta}");
            // Along the normal, a small offset is the distance.
            let h = 1e-6;
            let tangent = (outline.point(theta + h) - outline.point(theta - h)).normalize();
            let normal = Vector2::new(tangent.y, -tangent.x);
            let off = outline.distance(&(p + 0.01 * normal));
            assert!((off - 0.01).abs() < 2e-4, "{theta}: {off}");
        }
    }

    #[test]
    fn arms_rise_with_phase() {
        let arm_tip_height = |c: f64| {
            let outline = Outline::new(c);
            // The right arm is the farthest point in the right half-plane's upper part.
            (0..900)
                .map(|i| outline.point((i as f64 / 10.0 - 45.0).to_radians()))
                .max_by(|p, q| p.norm().total_cmp(&q.norm()))
                .unwrap()
                .y
        };
        assert!(arm_tip_height(1.0) > arm_tip_height(0.0) + 0.3);
    }
}
