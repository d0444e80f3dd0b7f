//! While the end-stop barrier holds a robot back, the policy follows its own latent state:
//! the one piece of state in an otherwise memoryless joint-range controller.
//!
//! Under a joint range ([`crate::flow::layers::joint_range`]) the field's paths stay
//! inside the limits but may run within micrometres of one, while the barrier on the
//! measured state holds a joint [`BARRIER_MARGIN`] off its stop. A memoryless policy
//! reads its latent state `z = f⁻¹(q, c)` from the measured joints, so a held joint holds
//! the latent state too. Where the field at the held state still points into the stops,
//! the free joints can come to rest as well: the motion stands still short of the
//! attractor (through the Panda, about one rollout in a thousand from starts spread over
//! the joint ranges; README "Joint limits").
//!
//! A hold **engages** when a joint is within [`HOLD_BAND`] of a limit and the desired
//! velocity points at that limit. From then on the policy runs a reference in its latent
//! space from `z_r = f⁻¹(q, c)`,
//!
//! `z_r ← φ(z_r, Δt s(y_r, v_r))`, `y_r = f(z_r, c)`, `v_r = s J_f(z_r) ż(z_r)`,
//!
//! the time-scaled noise-free motion (`φ(z, t)` the latent's exact flow over `t`, `s` the
//! speed scaling of the joint range; an Euler step `z_r + Δt s ż` would contract only
//! while the latent's rates stay below `2 / (Δt s)`), and reads
//! the field at `(y_r, v_r)` instead of the measurement. The velocity loop tracks
//! `s(q, w) w`, `w = v_r + (K_v/4)(y_r − q)`: a pull back onto the reference wherever the
//! barrier lets the robot go, slowed by the same time scaling at the measured `q` into
//! the speed and braking bounds. The hold
//! **releases** — the policy reads the measurement again — once the robot is within
//! [`BARRIER_MARGIN`] of the reference in every joint and the reference no longer moves
//! at a limit within the band.
//!
//! What this gives: the reference is the latent system's own trajectory, whatever the
//! barrier does to the robot, so it converges to the attractor (inside the limits) for
//! every context and weight value, and a hold cannot last past the reference's arrival
//! and the robot's catching up with it, which the measured robot loop shows (`ciflow
//! stability --robot-loop`). Without a hold the reading is the measurement and the
//! command is exactly the memoryless
//! [`Policy::acceleration`](crate::flow::Policy::acceleration).

use crate::flow::error::{FlowResult, invalid};
use crate::flow::layers::joint_range::{BARRIER_MARGIN, JointRange};

/// Distance from a limit (rad or m) within which a joint whose desired velocity points at
/// that limit engages the hold: twice the barrier's margin, so the spring's hold point is
/// inside.
pub const HOLD_BAND: f64 = 2.0 * BARRIER_MARGIN;

/// The hold of one robot (one episode at a time) under a joint-range policy; see the
/// module docs.
#[derive(Clone, Debug)]
pub struct EndStopHold {
    pub(crate) period: f64,
    pub(crate) engaged: bool,
    /// `z_r` while engaged.
    pub(crate) latent: Vec<f64>,
    /// `(y_r, v_r)` while engaged, else the measurement: what the policy last read.
    pub(crate) position: Vec<f64>,
    pub(crate) velocity: Vec<f64>,
}

impl EndStopHold {
    /// A hold for `dof` joints commanded every `period` seconds, released.
    pub fn new(dof: usize, period: f64) -> FlowResult<Self> {
        if !(period.is_finite() && period > 0.0) {
            return Err(invalid(format!(
                "end-stop hold: the control period must be finite and > 0, got {period}"
            )));
        }
        Ok(Self {
            period,
            engaged: false,
            latent: vec![0.0; dof],
            position: vec![0.0; dof],
            velocity: vec![0.0; dof],
        })
    }

    pub fn dof(&self) -> usize {
        self.latent.len()
    }

    /// Releases the hold (a new episode).
    pub fn clear(&mut self) {
        self.engaged = false;
    }

    /// Whether the policy follows its own latent state.
    pub fn is_engaged(&self) -> bool {
        self.engaged
    }

    /// The positions the policy read in the last period: the reference `y_r` while
    /// engaged, else the measurement.
    pub fn reading(&self) -> &[f64] {
        &self.position
    }

    /// Whether a joint of `y` within [`HOLD_BAND`] of a limit has its velocity `v`
    /// pointing at that limit.
    pub(crate) fn drives_into_a_limit(range: &JointRange, y: &[f64], v: &[f64]) -> bool {
        (0..y.len()).any(|i| {
            let room = match v[i] {
                v if v > 0.0 => range.position_max[i] - y[i],
                v if v < 0.0 => y[i] - range.position_min[i],
                _ => f64::INFINITY,
            };
            room <= HOLD_BAND
        })
    }

    /// Whether the robot at `q` has caught up with the reference in every joint.
    pub(crate) fn caught_up(&self, q: &[f64]) -> bool {
        self.position
            .iter()
            .zip(q)
            .all(|(y, q)| (y - q).abs() <= BARRIER_MARGIN)
    }
}
