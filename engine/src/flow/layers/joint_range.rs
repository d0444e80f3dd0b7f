//! A robot's limits built into the policy: the last layer of `f` maps every state into the
//! joints' position ranges, and the commands it derives are scaled into the speed and
//! acceleration limits without moving the fixed point.
//!
//! **Position: the last layer.** Per joint `i`, with `m = (q_max + q_min)/2` and
//! `h = (q_max − q_min)/2`,
//!
//! `y_i = R(u)_i = m_i + h_i tanh(u_i)`, `log|det ∂R/∂u| = Σ_i ln(h_i (1 − tanh² u_i))`,
//!
//! a diffeomorphism of ℝᵈ onto the open box `(q_min, q_max)`. (The algebraic
//! `u / √(1 + u²)` in place of `tanh`, whose tails keep far states centimetres rather
//! than millimetres from a limit, measured worse through the Panda: README "Joint
//! limits".) With it last,
//! `f = R ∘ f₀` is a diffeomorphism of the latent space onto the box for every context
//! and weight value, so the attractor `f(0, c)` and every trajectory of the noise-free
//! policy lie strictly inside the limits, and the latent system's stability carries
//! over as before. The velocity field `J_f v` vanishes towards a limit as `1 − tanh²`:
//! no motion of the field reaches an end stop.
//!
//! In `f64`, `tanh` rounds to `±1` beyond `|u| ≈ 19`, so both directions work with
//! `|tanh u| ≤ 1 − ε`, `ε` = [`EDGE`]: the policy's states stay `ε h` inside every limit.
//!
//! A measured state on a limit (an end stop holds the robot there) is read `ε h` inside
//! it, where the latent is about `½ ln(2/ε) ≈ 14` units out: a few latent time constants
//! from the data.
//!
//! **Speed: a time scaling.** The policy's desired velocity `v = J_f(z) ż` at `y` becomes
//!
//! `v̂ = s v`, `s = (1 + Σ_i [(v_i / v̄_i)⁸ + (v_i² / (2 β ā_i δ_i))⁴])^{−1/8}`,
//!
//! `δ_i` the distance from `y_i` to the limit `v_i` points at and `β` = [`BRAKING_SHARE`]:
//! a positive scalar times the field, so the same paths, traversed more slowly where they
//! would be too fast, and the fixed point, every trajectory's path and its convergence are
//! kept (`s > 0` is smooth inside the limits — each term is even in `v_i` to eighth
//! order — and bounded below on compact sets inside them). Since `s⁸ Σ < 1`, every
//! `|v̂_i| < v̄_i` and `|v̂_i| < √(2 β ā_i δ_i)`: braking at `β ā_i` stops a joint before
//! its limit. Away from the limits, where the speed term dominates: `s > 0.9995` while
//! `‖v ⊘ v̄‖₈ ≤ ½`, and `s = 0.975` at 0.83.
//!
//! **Acceleration: a common factor.** The field's desired acceleration `a` is divided by
//! `max(1, max_i |a_i| / (α ā_i))`: its direction is kept and it is unchanged near the
//! attractor (where `a → 0`). The share `α` of the bound depends on how far the latent
//! state is from the data: `α = 1` while `‖z‖ ≤ r₁`, falling linearly to
//! [`PLANNING_SHARE`] at `r₂` and beyond ([`SHARE_RADII`]; the network's input is
//! normalised, and pushed pouring states have `‖z‖ ≈ 0.5` at the median). Near the data
//! a pushed robot returns with the whole bound; far from it, where the learned field turns
//! within tens of milliseconds, the rest is headroom for the barrier below and for the
//! torque-rate limit. (Clipping each joint instead, as the pouring action space does,
//! measured worse through the Panda.) Unlike the two maps above this is not a
//! reparametrisation of the field, so convergence through it is measured (`ciflow
//! stability --robot-loop`), not proved.
//!
//! **End stops: a barrier on the measured state.** The field stays inside the limits, but
//! far from the data it can run along one within micrometres, and the robot's tracking
//! error is larger than that. Each joint's acceleration is therefore kept within bounds
//! set by its measured `(q_i, q̇_i)`, on its own (a per-joint override, not a time
//! scaling). Towards the upper limit at distance `δ = q_max − q` (the lower one is
//! mirrored), with braking `b = β ā`, `β` = [`BRAKING_SHARE`]:
//!
//! - braking: `h = 2 b δ − q̇² ≥ 0` says the joint can still stop before the limit at `b`;
//!   for `q̇ > 0` the bound `a ≤ −b + γ h / (2 q̇)` gives `ḣ ≥ −γ h`, so `h` stays
//!   non-negative (`γ` = [`BARRIER_RATE`]);
//! - spring: `a ≤ ω² (δ − m) − 2 ω q̇`, a critically damped spring (`ω` =
//!   [`BARRIER_STIFFNESS`]) that holds a slow joint `m` = [`BARRIER_MARGIN`] off the stop,
//!   where the path would graze it;
//!
//! both clamped into `±ā`. With the command realised exactly, a joint inside its
//! braking envelope never reaches its stop; through the torque-limited robot this is
//! measured. Both bounds are inactive at rest more than `m` inside the limits, so such a
//! rest point of the policy (its attractor, in particular) is kept.

use serde::{Deserialize, Serialize};

use crate::flow::error::{FlowResult, invalid};
use crate::model::JointLimits;
use crate::nn::scalar::Scalar;

/// How far inside a limit `|tanh u| < 1 − ε` a state on or beyond it is read.
pub const EDGE: f64 = 1e-12;

/// Share `β` of the acceleration bound that the speed near a limit leaves for braking;
/// the rest is for following the field's curvature and the velocity feedback.
pub const BRAKING_SHARE: f64 = 0.5;

/// Share `α` of the acceleration bound the field's own acceleration is scaled into far
/// from the data. Through the Panda, 0.5 took the saturated control steps from 1.2–2.5 %
/// to 0.2–1.2 %, and 0.25 to 0.04–0.44 % over three trainings and four sets of starts
/// (README "Joint limits"). What saturates far from the data is the torque rate, while
/// the field's direction turns from one control period to the next: a smaller share
/// makes those turns smaller steps of torque.
pub const PLANNING_SHARE: f64 = 0.25;

/// `(r₁, r₂)`: latent norms up to which the field may use the whole acceleration bound,
/// and from which it gets [`PLANNING_SHARE`]. Pushed pouring states reach `‖z‖ ≈ 12` (99th
/// percentile); the robot loop's far starts 80 and more.
pub const SHARE_RADII: (f64, f64) = (5.0, 20.0);

/// `γ` (1/s): how fast the braking barrier `h = 2 b δ − q̇²` may shrink, `ḣ ≥ −γ h`.
pub const BARRIER_RATE: f64 = 3.0;

/// `ω` (rad/s) of the critically damped spring that holds a joint off its stop.
pub const BARRIER_STIFFNESS: f64 = 10.0;

/// `m`: how far off a stop the spring holds a joint, in the joint's unit (rad or m).
pub const BARRIER_MARGIN: f64 = 0.003;

/// A robot's joint limits as a policy respects them (raw units: rad or m, per second).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct JointRange {
    /// `q_min`, `q_max`: the open interval every state of the policy stays in.
    pub position_min: Vec<f64>,
    pub position_max: Vec<f64>,
    /// `v̄`: the bound of the time-scaled desired velocity.
    pub speed_max: Vec<f64>,
    /// `ā`: the bound of the desired acceleration.
    pub acceleration_max: Vec<f64>,
}

impl JointRange {
    /// Checks `dof` entries each, `q_min < q_max` finite, and positive finite bounds.
    pub fn validate(&self, dof: usize) -> FlowResult<()> {
        let fields = [
            ("position_min", &self.position_min),
            ("position_max", &self.position_max),
            ("speed_max", &self.speed_max),
            ("acceleration_max", &self.acceleration_max),
        ];
        for (name, values) in fields {
            if values.len() != dof {
                return Err(invalid(format!(
                    "joint_range.{name} has {} entries, the state {dof}",
                    values.len()
                )));
            }
            if values.iter().any(|v| !v.is_finite()) {
                return Err(invalid(format!("joint_range.{name} must be finite")));
            }
        }
        if let Some(i) = (0..dof).find(|&i| self.position_min[i] >= self.position_max[i]) {
            return Err(invalid(format!(
                "joint_range: joint {i} needs position_min < position_max ({} >= {})",
                self.position_min[i], self.position_max[i]
            )));
        }
        if self
            .speed_max
            .iter()
            .chain(&self.acceleration_max)
            .any(|&v| v <= 0.0)
        {
            return Err(invalid(
                "joint_range.speed_max and acceleration_max must be > 0".into(),
            ));
        }
        Ok(())
    }

    /// A robot's position ranges, speed limits and acceleration limits.
    pub fn from_limits(limits: &JointLimits) -> Self {
        Self {
            position_min: limits.q_min.as_slice().to_vec(),
            position_max: limits.q_max.as_slice().to_vec(),
            speed_max: limits.qd_max.as_slice().to_vec(),
            acceleration_max: limits.qdd_max.as_slice().to_vec(),
        }
    }

    fn centre(&self, i: usize) -> f64 {
        0.5 * (self.position_max[i] + self.position_min[i])
    }

    fn half_width(&self, i: usize) -> f64 {
        0.5 * (self.position_max[i] - self.position_min[i])
    }

    /// `y ← R(u)`; returns `log|det ∂R/∂u|`.
    pub fn apply<S: Scalar>(&self, u: &mut [S]) -> S {
        let mut log_det = S::constant(0.0);
        for (i, x) in u.iter_mut().enumerate() {
            let h = self.half_width(i);
            // ln(1 − tanh² u) = 2 ln 2 − 2u − 2 softplus(−2u), finite for every u.
            log_det +=
                (*x * -2.0).softplus() * -2.0 + *x * -2.0 + (2.0 * std::f64::consts::LN_2 + h.ln());
            *x = clamp_inside(x.tanh()) * h + self.centre(i);
        }
        log_det
    }

    /// `u ← R⁻¹(y)` (states on or beyond a limit read `ε h` inside it); returns
    /// `log|det ∂R⁻¹/∂y|`. Writes `tanh u` to `record` when given, for
    /// [`tangent`](Self::tangent).
    pub fn invert<S: Scalar>(&self, y: &mut [S], mut record: Option<&mut [f64]>) -> S {
        let mut log_det = S::constant(0.0);
        for (i, x) in y.iter_mut().enumerate() {
            let (u, log_derivative, t) = self.invert_coordinate(i, *x);
            *x = u;
            log_det += log_derivative;
            if let Some(record) = record.as_deref_mut() {
                record[i] = t;
            }
        }
        log_det
    }

    /// `R⁻¹(y)_i` for one coordinate, in `f64` (for data statistics).
    pub fn unbounded(&self, i: usize, value: f64) -> f64 {
        self.invert_coordinate(i, value).0
    }

    /// `(u_i, ln ∂u_i/∂y_i, tanh u_i)` for `y_i = value`.
    fn invert_coordinate<S: Scalar>(&self, i: usize, value: S) -> (S, S, f64) {
        let h = self.half_width(i);
        let t = clamp_inside((value + -self.centre(i)) * (1.0 / h));
        let (plus, minus) = ((t + 1.0).ln(), (-t + 1.0).ln());
        ((plus + -minus) * 0.5, -(plus + minus) + -h.ln(), t.value())
    }

    /// `dy ← ∂R/∂u · dy` at the `tanh u` recorded by [`invert`](Self::invert).
    pub fn tangent(&self, record: &[f64], dy: &mut [f64]) {
        for (i, (d, t)) in dy.iter_mut().zip(record).enumerate() {
            *d *= self.half_width(i) * (1.0 - t * t);
        }
    }

    /// `s(y, v)`, the time scaling that keeps the desired velocity `s v` within `v̄` and
    /// within braking distance of the limits.
    pub fn speed_scale<S: Scalar>(&self, position: &[S], velocity: &[S]) -> S {
        let mut sum = S::constant(0.0);
        for (i, (&y, &v)) in position.iter().zip(velocity).enumerate() {
            let v2 = v * v;
            let r2 = v2 * (1.0 / (self.speed_max[i] * self.speed_max[i]));
            let r4 = r2 * r2;
            let distance = match v.value() >= 0.0 {
                true => -y + self.position_max[i],
                false => y + -self.position_min[i],
            };
            let floor = EDGE * self.half_width(i);
            let distance = match distance.value() > floor {
                true => distance,
                false => S::constant(floor),
            };
            let w = v2 / (distance * (2.0 * BRAKING_SHARE * self.acceleration_max[i]));
            let w2 = w * w;
            sum += r4 * r4 + w2 * w2;
        }
        ((sum + 1.0).ln() * (-1.0 / 8.0)).exp()
    }

    /// `α(‖z‖)`: the share of the acceleration bound the field gets at latent norm `‖z‖`.
    pub fn acceleration_share(latent_norm: f64) -> f64 {
        let (near, far) = SHARE_RADII;
        let farness = ((latent_norm - near) / (far - near)).clamp(0.0, 1.0);
        1.0 - (1.0 - PLANNING_SHARE) * farness
    }

    /// The commanded acceleration at the measured `(q, q̇)`, whose latent state has norm
    /// `latent_norm`: `a` scaled into `α(‖z‖) ā` along its direction, then each joint kept
    /// within its end-stop barrier and `±ā`.
    pub fn limit_acceleration(
        &self,
        position: &[f64],
        velocity: &[f64],
        latent_norm: f64,
        acceleration: &mut [f64],
    ) {
        let share = Self::acceleration_share(latent_norm);
        let excess = acceleration
            .iter()
            .zip(&self.acceleration_max)
            .map(|(a, bound)| a.abs() / (share * bound))
            .fold(1.0, f64::max);
        for (i, a) in acceleration.iter_mut().enumerate() {
            let (least, most) = self.barrier(i, position[i], velocity[i]);
            *a = (*a / excess).min(most).max(least);
        }
    }

    /// `(lowest, highest)` acceleration of joint `i` at `(q, q̇)` that its end-stop barrier
    /// allows, within `±ā` (the lower bound wins if they cross).
    pub fn barrier(&self, i: usize, q: f64, v: f64) -> (f64, f64) {
        let bound = self.acceleration_max[i];
        let braking = BRAKING_SHARE * bound;
        let omega = BARRIER_STIFFNESS;
        let spring = |room: f64| omega * omega * (room - BARRIER_MARGIN);
        let (room_up, room_down) = (self.position_max[i] - q, q - self.position_min[i]);
        let mut most = spring(room_up) - 2.0 * omega * v;
        let mut least = -spring(room_down) - 2.0 * omega * v;
        // `h = 2 b δ − q̇²` towards the limit the joint moves to, kept by `ḣ ≥ −γ h`.
        let stop = |room: f64, speed: f64| {
            -braking + BARRIER_RATE * (2.0 * braking * room - speed * speed) / (2.0 * speed)
        };
        if v > 0.0 {
            most = most.min(stop(room_up, v));
        } else if v < 0.0 {
            least = least.max(-stop(room_down, -v));
        }
        (least.min(bound), most.max(-bound))
    }
}

/// `t` with `|t| ≤ 1 − ε` ([`EDGE`]); a clamped value is a constant.
fn clamp_inside<S: Scalar>(t: S) -> S {
    let edge = 1.0 - EDGE;
    match t.value().abs() > edge {
        true => S::constant(edge.copysign(t.value())),
        false => t,
    }
}

#[cfg(test)]
mod tests {
    use super::{BARRIER_MARGIN, BRAKING_SHARE, JointRange, PLANNING_SHARE, SHARE_RADII};
    use crate::nn::scalar::Dual;

    fn range() -> JointRange {
        JointRange {
            position_min: vec![-2.0, 0.5],
            position_max: vec![1.0, 3.5],
            speed_max: vec![1.0, 2.0],
            acceleration_max: vec![10.0, 5.0],
        }
    }

    #[test]
    fn invert_undoes_apply_and_log_dets_cancel() {
        let range = range();
        for u0 in [[0.3, -1.2], [4.0, -6.0], [-15.0, 18.0]] {
            let mut y = u0;
            let forward = range.apply(&mut y);
            assert!(y[0] > -2.0 && y[0] < 1.0 && y[1] > 0.5 && y[1] < 3.5);
            assert!(forward.is_finite(), "log-det at {u0:?}");
            if u0[0].abs() < 10.0 {
                let mut u = y;
                let inverse = range.invert(&mut u, None);
                assert!((u[0] - u0[0]).abs() < 1e-9 && (u[1] - u0[1]).abs() < 1e-9);
                assert!((forward + inverse).abs() < 1e-9);
            }
        }
    }

    #[test]
    fn log_det_and_tangent_match_finite_differences() {
        let range = range();
        let u0 = [0.4, -0.9];
        let mut y = u0;
        let log_det = range.apply(&mut y);
        let mut record = [0.0; 2];
        range.invert(&mut y.clone(), Some(&mut record));
        let step = 1e-6;
        let mut expected = 0.0;
        for i in 0..2 {
            let (mut plus, mut minus) = (u0, u0);
            plus[i] += step;
            minus[i] -= step;
            range.apply(&mut plus);
            range.apply(&mut minus);
            let derivative = (plus[i] - minus[i]) / (2.0 * step);
            expected += derivative.ln();
            let mut dy = [0.0; 2];
            dy[i] = 1.0;
            range.tangent(&record, &mut dy);
            assert!((dy[i] - derivative).abs() < 1e-8, "joint {i}");
        }
        assert!((log_det - expected).abs() < 1e-8);
    }

    #[test]
    fn states_on_a_limit_are_read_just_inside_it() {
        let range = range();
        let mut y = [1.0, 0.0];
        let log_det = range.invert(&mut y, None);
        assert!(y.iter().all(|u| u.is_finite() && u.abs() > 13.0));
        assert!(y[0] > 0.0 && y[1] < 0.0, "each on its own side: {y:?}");
        assert!(log_det.is_finite());
    }

    #[test]
    fn scaled_speed_stays_within_its_bound_and_braking_distance() {
        let range = range();
        let braking = |y: f64, v: f64, i: usize| {
            let limit = if v >= 0.0 {
                range.position_max[i]
            } else {
                range.position_min[i]
            };
            (2.0 * BRAKING_SHARE * range.acceleration_max[i] * (limit - y).abs()).sqrt()
        };
        for (y, v) in [
            ([0.0, 2.0], [0.5, -0.2]),
            ([-1.9, 3.4], [3.0, 0.1]),
            ([0.99, 0.51], [-40.0, 90.0]),
            ([-1.0, 2.0], [-3.0, -4.0]),
        ] {
            let s = range.speed_scale(&y, &v);
            assert!(s > 0.0 && s <= 1.0);
            for i in 0..2 {
                assert!((s * v[i]).abs() < range.speed_max[i], "{y:?} {v:?}");
                assert!((s * v[i]).abs() < braking(y[i], v[i], i), "{y:?} {v:?}");
            }
        }
        // Far from the limits, slow fields are left alone.
        assert!(range.speed_scale(&[-0.5, 2.0], &[0.5, 0.5]) > 0.9995);
        // The dual part is d/dt of s(y(t), v(t)).
        let (y, dy, v, dv) = ([0.2, 1.1], [0.4, -0.7], [0.8, -1.5], [0.3, 2.0]);
        let dual = |a: [f64; 2], b: [f64; 2]| [Dual::new(a[0], b[0]), Dual::new(a[1], b[1])];
        let s = range.speed_scale(&dual(y, dy), &dual(v, dv));
        let h = 1e-7;
        let at = |t: f64| {
            let shift = |a: [f64; 2], b: [f64; 2]| [a[0] + t * b[0], a[1] + t * b[1]];
            range.speed_scale(&shift(y, dy), &shift(v, dv))
        };
        assert!((s.du - (at(h) - at(-h)) / (2.0 * h)).abs() < 1e-7);
    }

    #[test]
    fn acceleration_keeps_its_direction_within_its_share() {
        let range = range();
        // At rest in the middle of both ranges the barrier is inactive.
        let (middle, rest) = ([-0.5, 2.0], [0.0, 0.0]);
        let (near, far) = SHARE_RADII;
        for (latent_norm, share) in [
            (0.0, 1.0),
            (near, 1.0),
            (far, PLANNING_SHARE),
            (1e3, PLANNING_SHARE),
        ] {
            let mut a = [20.0, -2.0];
            range.limit_acceleration(&middle, &rest, latent_norm, &mut a);
            let excess = 20.0 / (share * 10.0);
            assert_eq!(a, [20.0 / excess, -2.0 / excess], "at |z| = {latent_norm}");
            // Inside the smallest share, [`PLANNING_SHARE`] of `ā = (10, 5)`.
            let mut small = [1.0, -1.0];
            range.limit_acceleration(&middle, &rest, latent_norm, &mut small);
            assert_eq!(small, [1.0, -1.0]);
        }
        // Continuous in between.
        let middle_share = JointRange::acceleration_share(0.5 * (near + far));
        assert!((middle_share - 0.5 * (1.0 + PLANNING_SHARE)).abs() < 1e-12);
    }

    /// Joint 0 driven towards its upper limit with the largest demand, integrated at 1 ms
    /// for 5 s; returns its closest approach, final distance and final speed.
    fn drive_to_the_limit(range: &JointRange, qd0: f64, barrier: bool) -> (f64, f64, f64) {
        let far = SHARE_RADII.1;
        let (h, mut q, mut qd, mut closest) = (1e-3, [0.0, 2.0], [qd0, 0.0], f64::INFINITY);
        for _ in 0..5000 {
            let mut a = [1e3, 0.0];
            match barrier {
                true => range.limit_acceleration(&q, &qd, far, &mut a),
                false => a[0] = PLANNING_SHARE * range.acceleration_max[0],
            }
            qd[0] += h * a[0];
            q[0] += h * qd[0];
            closest = closest.min(range.position_max[0] - q[0]);
        }
        (closest, range.position_max[0] - q[0], qd[0])
    }

    #[test]
    fn the_barrier_stops_a_joint_before_its_limit_and_holds_it_off() {
        let range = range();
        // From rest, and from a speed that braking at `β ā` could not stop in time.
        for qd0 in [0.0, 4.0] {
            let (closest, gap, speed) = drive_to_the_limit(&range, qd0, true);
            assert!(
                closest > 0.0,
                "reached the stop from {qd0} rad/s: {closest}"
            );
            assert!(
                (gap - BARRIER_MARGIN).abs() < 1e-3 && speed.abs() < 1e-3,
                "{gap} {speed}"
            );
            // Negative control: the same demand without the barrier runs through the stop.
            assert!(drive_to_the_limit(&range, qd0, false).0 < 0.0);
        }
        // At rest within the margin the spring pushes the joint off the stop, mirrored at
        // the lower limit; more than the margin inside, rest stays rest.
        let at_rest_off_the_stops = |margins: f64| {
            let mut a = [0.0, 0.0];
            let q = [
                1.0 - margins * BARRIER_MARGIN,
                0.5 + margins * BARRIER_MARGIN,
            ];
            range.limit_acceleration(&q, &[0.0; 2], 0.0, &mut a);
            a
        };
        let within = at_rest_off_the_stops(0.5);
        assert!(within[0] < 0.0 && within[1] > 0.0, "{within:?}");
        assert_eq!(at_rest_off_the_stops(2.0), [0.0, 0.0]);
    }

    #[test]
    fn validation_refuses_empty_ranges_and_bad_bounds() {
        let mut bad = range();
        bad.position_min[1] = 3.5;
        assert!(bad.validate(2).is_err());
        let mut bad = range();
        bad.speed_max[0] = 0.0;
        assert!(bad.validate(2).is_err());
        assert!(range().validate(3).is_err());
        assert!(range().validate(2).is_ok());
    }
}
