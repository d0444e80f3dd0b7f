//! The conditioned ImitationFlow policy: latent dynamics seen through `y = f(z, c)`.
//!
//! Everything is `f64` and allocation-free after [`Policy::workspace`]: the network,
//! its Jacobian-vector products (dual numbers) and the densities (one-step).

use std::path::Path;

use rand::Rng;

use crate::math::distance;

use crate::flow::checkpoint;
use crate::flow::checkpoint::config::{CheckpointConfig, FlowConfig};
use crate::flow::checkpoint::weights::Weights;
use crate::flow::end_stop_hold::EndStopHold;
use crate::flow::error::{FlowError, FlowResult, check_input};
use crate::flow::latent::{LatentDynamics, LatentFlowScratch};
use crate::flow::layers::coupling::{CouplingScratch, TangentScratch};
use crate::flow::layers::joint_range::JointRange;
use crate::flow::network::{ConditionalFlow, Conditioning, FlowTape};
use crate::flow::sampled_control::limit_overshoot;
use crate::nn::scalar::{Dual, Scalar};

type Dual2 = Dual<Dual<f64>>;

#[derive(Clone, Debug)]
pub struct Policy {
    flow: ConditionalFlow,
    latent: LatentDynamics,
}

/// Preallocated buffers for [`Policy`] calls (one per thread).
#[derive(Clone, Debug)]
pub struct PolicyWorkspace {
    conditioning: Conditioning,
    scratch: CouplingScratch<f64>,
    scratch_dual: CouplingScratch<Dual<f64>>,
    /// The last inverse pass, for Jacobian-vector products at its `z`.
    tape: FlowTape,
    /// The last inverse pass in dual numbers, for [`Policy::acceleration`]'s forward pass.
    dual_tape: FlowTape,
    tangent: TangentScratch,
    z: Vec<f64>,
    z_next: Vec<f64>,
    /// The matrix exponentials of an engaged hold's latent step.
    latent_flow: LatentFlowScratch,
    /// `z_k` of a transition while `z` holds `z_{k-1}`.
    z_later: Vec<f64>,
    mean: Vec<f64>,
    origin: Vec<f64>,
    latent_velocity: Vec<f64>,
    /// The velocity the robot's velocity loop tracks under an engaged [`EndStopHold`].
    tracked_velocity: Vec<f64>,
    dual: Vec<Dual<f64>>,
    dual_z: Vec<Dual<f64>>,
    dual_velocity: Vec<Dual<f64>>,
    dual2: Vec<Dual2>,
    dual2_y: Vec<Dual2>,
}

impl Policy {
    /// Builds the policy, taking every parameter of `config` out of `weights`; any
    /// missing, extra or mis-shaped tensor is an error.
    pub fn new(config: &FlowConfig, mut weights: Weights) -> FlowResult<Self> {
        let flow = ConditionalFlow::from_weights(config, &mut weights)?;
        let latent = LatentDynamics::from_weights(config, &mut weights)?;
        weights.finish()?;
        Ok(Self { flow, latent })
    }

    /// Loads a flow checkpoint directory; `expected_task` guards against the wrong task.
    pub fn load(dir: &Path, expected_task: Option<&str>) -> FlowResult<Self> {
        match checkpoint::read(dir, expected_task)? {
            (CheckpointConfig::Flow(config), weights) => Self::new(&config, weights),
            (other, _) => Err(FlowError::ModelMismatch {
                expected: "flow",
                found: other.model_name(),
            }),
        }
    }

    pub fn config(&self) -> &FlowConfig {
        self.flow.config()
    }

    /// This flow with its latent run backwards in time
    /// ([`LatentDynamics::time_reversed`]): the stability check's negative control, of
    /// the same class as the policy it checks.
    pub fn time_reversed(&self) -> Self {
        Self {
            flow: self.flow.clone(),
            latent: self.latent.time_reversed(),
        }
    }

    pub fn network(&self) -> &ConditionalFlow {
        &self.flow
    }

    pub fn latent(&self) -> &LatentDynamics {
        &self.latent
    }

    pub fn workspace(&self) -> PolicyWorkspace {
        let config = self.config();
        let d = config.state_dim;
        PolicyWorkspace {
            conditioning: self.flow.conditioning(),
            scratch: self.flow.scratch(),
            scratch_dual: self.flow.scratch(),
            tape: self.flow.tape(),
            dual_tape: self.flow.dual_tape(),
            tangent: self.flow.tangent_scratch(),
            z: vec![0.0; d],
            z_next: vec![0.0; d],
            latent_flow: self.latent.flow_scratch(),
            z_later: vec![0.0; d],
            mean: vec![0.0; d],
            origin: vec![0.0; d],
            latent_velocity: vec![0.0; d],
            tracked_velocity: vec![0.0; d],
            dual: vec![Dual::new(0.0, 0.0); d],
            dual_z: vec![Dual::new(0.0, 0.0); d],
            dual_velocity: vec![Dual::new(0.0, 0.0); d],
            dual2: vec![Dual::new(Dual::new(0.0, 0.0), Dual::new(0.0, 0.0)); d],
            dual2_y: vec![Dual::new(Dual::new(0.0, 0.0), Dual::new(0.0, 0.0)); d],
        }
    }

    /// Checks `y` and `c`, prepares the context and leaves `z = f⁻¹(y, c)` in `ws.z`;
    /// returns `log|det ∂f⁻¹/∂y|`.
    fn invert(&self, y: &[f64], context: &[f64], ws: &mut PolicyWorkspace) -> FlowResult<f64> {
        check_input("state", self.config().state_dim, y)?;
        self.flow
            .condition(context, &mut ws.conditioning, &mut ws.scratch)?;
        Ok(self
            .flow
            .inverse(y, &ws.conditioning, &mut ws.scratch, &mut ws.z))
    }

    /// Like [`invert`](Self::invert), recording the pass in `ws.tape`, and leaves the
    /// latent velocity `v(z)` in `ws.latent_velocity`.
    fn invert_recorded(
        &self,
        y: &[f64],
        context: &[f64],
        ws: &mut PolicyWorkspace,
    ) -> FlowResult<()> {
        check_input("state", self.config().state_dim, y)?;
        self.flow
            .condition(context, &mut ws.conditioning, &mut ws.scratch)?;
        self.flow.inverse_recorded(
            y,
            &ws.conditioning,
            &mut ws.scratch,
            &mut ws.z,
            &mut ws.tape,
        );
        self.latent.velocity(&ws.z, &mut ws.latent_velocity);
        Ok(())
    }

    fn check_output(&self, out: &[f64]) -> FlowResult<()> {
        crate::flow::error::check_dim("output", self.config().state_dim, out)
    }

    /// `z = f⁻¹(y, c)`.
    pub fn latent_state(
        &self,
        y: &[f64],
        context: &[f64],
        ws: &mut PolicyWorkspace,
        z: &mut [f64],
    ) -> FlowResult<()> {
        self.check_output(z)?;
        self.invert(y, context, ws)?;
        z.copy_from_slice(&ws.z);
        Ok(())
    }

    /// `y = f(z, c)`.
    pub fn observe(
        &self,
        z: &[f64],
        context: &[f64],
        ws: &mut PolicyWorkspace,
        y: &mut [f64],
    ) -> FlowResult<()> {
        self.check_output(y)?;
        check_input("latent state", self.config().state_dim, z)?;
        self.flow
            .condition(context, &mut ws.conditioning, &mut ws.scratch)?;
        self.flow.forward(z, &ws.conditioning, &mut ws.scratch, y);
        Ok(())
    }

    /// Noise-free next state `y_{k+1} = f(μ(f⁻¹(y_k, c)), c)`.
    pub fn mean_next(
        &self,
        y: &[f64],
        context: &[f64],
        ws: &mut PolicyWorkspace,
        out: &mut [f64],
    ) -> FlowResult<()> {
        self.check_output(out)?;
        self.invert(y, context, ws)?;
        self.latent.mean_step(&ws.z, &mut ws.z_next);
        self.flow
            .forward(&ws.z_next, &ws.conditioning, &mut ws.scratch, out);
        Ok(())
    }

    /// A sample `y_{k+1} ~ p(· | y_k, c)`.
    pub fn sample_next(
        &self,
        y: &[f64],
        context: &[f64],
        rng: &mut impl Rng,
        ws: &mut PolicyWorkspace,
        out: &mut [f64],
    ) -> FlowResult<()> {
        self.check_output(out)?;
        self.invert(y, context, ws)?;
        self.latent.sample_step(&ws.z, rng, &mut ws.z_next);
        self.flow
            .forward(&ws.z_next, &ws.conditioning, &mut ws.scratch, out);
        Ok(())
    }

    /// Desired velocity `ẏ_des = J_f(z) v(z)` at `z = f⁻¹(y, c)`: the inverse pass keeps
    /// its conditioner activations, and one tangent sweep through `f` seeded with the
    /// latent velocity reuses them (the forward pass at `z` meets the same coupling
    /// inputs the inverse pass saw). Under a joint range it is time-scaled, `s(y, v) v`
    /// ([`crate::flow::layers::joint_range`]).
    pub fn velocity(
        &self,
        y: &[f64],
        context: &[f64],
        ws: &mut PolicyWorkspace,
        out: &mut [f64],
    ) -> FlowResult<()> {
        self.check_output(out)?;
        self.invert_recorded(y, context, ws)?;
        self.flow
            .tangent(&ws.tape, &ws.latent_velocity, &mut ws.tangent, out);
        self.limit_speed(y, out);
        Ok(())
    }

    /// `v ← s(y, v) v` under a joint range (its time scaling,
    /// [`crate::flow::layers::joint_range`]).
    fn limit_speed<S: Scalar>(&self, y: &[S], velocity: &mut [S]) {
        if let Some(range) = &self.config().joint_range {
            let s = range.speed_scale(y, velocity);
            velocity.iter_mut().for_each(|v| *v = *v * s);
        }
    }

    /// The full policy action of the benchmark: writes the mean next state
    /// `f(μ(z), c)` and the desired velocity `J_f(z) v(z)`, `z = f⁻¹(y, c)`.
    ///
    /// Two sweeps over the weights: the inverse pass records its activations, then one
    /// forward sweep evaluates `f(μ(z), c)` and, with the same weight loads, the tangent
    /// at `z` from the record (see [`velocity`](Self::velocity)).
    pub fn act(
        &self,
        y: &[f64],
        context: &[f64],
        ws: &mut PolicyWorkspace,
        next: &mut [f64],
        velocity: &mut [f64],
    ) -> FlowResult<()> {
        self.check_output(next)?;
        self.check_output(velocity)?;
        self.invert_recorded(y, context, ws)?;
        self.latent.mean_step(&ws.z, &mut ws.z_next);
        self.flow.forward_with_tangent(
            &ws.tape,
            &ws.z_next,
            &ws.conditioning,
            &ws.latent_velocity,
            &mut ws.tangent,
            next,
            velocity,
        );
        self.limit_speed(y, velocity);
        Ok(())
    }

    /// Desired acceleration for a second-order robot at position `q` and velocity `q̇`:
    ///
    /// `q̈_des = (∂v_des/∂q) q̇ + K_v (v_des(q) - q̇)`, `v_des(q) = J_f(z) v(z)`, `z = f⁻¹(q, c)`.
    ///
    /// The first term is `d/dt v_des(q(t))` along the actual motion, so under
    /// `q̈ = q̈_des` the velocity error `e = q̇ - v_des(q)` obeys `ė = -K_v e` exactly.
    /// Computed with nested dual numbers: the inverse is differentiated along `q̇`, the
    /// forward pass along `v(z)` and along that time direction at once. The forward
    /// pass retraces the inverse pass's points, so it takes the conditioners' values and
    /// time derivatives from the inverse pass's record and evaluates them only along
    /// `v(z)` ([`ConditionalFlow::forward_second`]).
    /// Writes `q̈_des` to `acceleration` and `v_des(q)` to `velocity`.
    ///
    /// Under a joint range, `v_des` is the time-scaled `s(q, v) v` (its `d/dt` through `s`
    /// included), and `q̈_des` is scaled into a share of the acceleration bounds that
    /// shrinks with the latent norm `‖z‖`, and kept off the end stops at the measured
    /// `(q, q̇)` ([`crate::flow::layers::joint_range`]). Memoryless: a robot driven by it
    /// can come to rest with joints held by the barrier; [`Self::acceleration_held`] is the
    /// controller for a robot.
    #[allow(clippy::too_many_arguments)]
    pub fn acceleration(
        &self,
        q: &[f64],
        qd: &[f64],
        context: &[f64],
        velocity_gain: f64,
        ws: &mut PolicyWorkspace,
        acceleration: &mut [f64],
        velocity: &mut [f64],
    ) -> FlowResult<()> {
        self.check_acceleration_arguments(q, qd, velocity_gain, acceleration, velocity)?;
        self.flow
            .condition(context, &mut ws.conditioning, &mut ws.scratch)?;
        self.acceleration_reading(q, qd, None, velocity_gain, ws, acceleration, velocity)
    }

    /// [`Self::acceleration`] for a robot that keeps `hold` from one control period to the
    /// next (one per robot, [`EndStopHold::clear`]ed at a new episode) and holds each
    /// command for the hold's period. Under a joint range, while the end-stop barrier holds
    /// the robot back the policy follows its own latent state
    /// ([`crate::flow::end_stop_hold`]); without a hold engaged the command is that of
    /// [`Self::acceleration`]. Without a joint range it is that command shortened along the
    /// motion where the field is so stiff that one period would overshoot
    /// ([`crate::flow::sampled_control`]; under a joint range the command is scaled into
    /// the acceleration bounds, no longer affine in `q̇` as the guard's reading of the
    /// stiffness needs).
    #[allow(clippy::too_many_arguments)]
    pub fn acceleration_held(
        &self,
        q: &[f64],
        qd: &[f64],
        context: &[f64],
        velocity_gain: f64,
        hold: &mut EndStopHold,
        ws: &mut PolicyWorkspace,
        acceleration: &mut [f64],
        velocity: &mut [f64],
    ) -> FlowResult<()> {
        self.check_acceleration_arguments(q, qd, velocity_gain, acceleration, velocity)?;
        let Some(range) = &self.config().joint_range else {
            self.acceleration(q, qd, context, velocity_gain, ws, acceleration, velocity)?;
            limit_overshoot(qd, velocity, velocity_gain, hold.period, acceleration);
            return Ok(());
        };
        if hold.dof() != q.len() {
            return Err(FlowError::InvalidConfig(format!(
                "end-stop hold for {} joints, the state has {}",
                hold.dof(),
                q.len()
            )));
        }
        self.flow
            .condition(context, &mut ws.conditioning, &mut ws.scratch)?;
        let reference = if hold.engaged {
            self.step_reference(range, hold, ws);
            Some((hold.position.as_slice(), hold.velocity.as_slice()))
        } else {
            None
        };
        self.acceleration_reading(q, qd, reference, velocity_gain, ws, acceleration, velocity)?;
        if hold.engaged {
            if hold.caught_up(q)
                && !EndStopHold::drives_into_a_limit(range, &hold.position, &hold.velocity)
            {
                hold.engaged = false;
            }
        } else {
            hold.position.copy_from_slice(q);
            hold.velocity.copy_from_slice(qd);
            if EndStopHold::drives_into_a_limit(range, q, velocity) {
                // The reference starts at `z = f⁻¹(q)`, which the pass just made left in
                // `dual_z`.
                hold.engaged = true;
                for (z, dual) in hold.latent.iter_mut().zip(&ws.dual_z) {
                    *z = dual.re;
                }
            }
        }
        Ok(())
    }

    /// Reads the reference of an engaged `hold` — `y_r = f(z_r, c)` and the time-scaled
    /// `v_r = s J_f(z_r) ż(z_r)`, from one forward pass along `ż(z_r)` — into
    /// `hold.position` and `hold.velocity`, then moves `z_r` one control period on. Needs
    /// `ws.conditioning` made for the context.
    fn step_reference(&self, range: &JointRange, hold: &mut EndStopHold, ws: &mut PolicyWorkspace) {
        self.latent.velocity(&hold.latent, &mut ws.latent_velocity);
        for ((d, z), v) in ws
            .dual
            .iter_mut()
            .zip(&hold.latent)
            .zip(&ws.latent_velocity)
        {
            *d = Dual::new(*z, *v);
        }
        self.flow.forward(
            &ws.dual,
            &ws.conditioning,
            &mut ws.scratch_dual,
            &mut ws.dual_velocity,
        );
        for (i, y) in ws.dual_velocity.iter().enumerate() {
            (hold.position[i], hold.velocity[i]) = (y.re, y.du);
        }
        let s = range.speed_scale(&hold.position, &hold.velocity);
        hold.velocity.iter_mut().for_each(|v| *v *= s);
        // The latent's exact flow over the time-scaled period: it contracts for every
        // weight, where an Euler step `z + Δt s ż` does only while the latent's rates stay
        // below `2 / (Δt s)`.
        self.latent.mean_after(
            &hold.latent,
            hold.period * s,
            &mut ws.latent_flow,
            &mut ws.z_next,
        );
        hold.latent.copy_from_slice(&ws.z_next);
    }

    fn check_acceleration_arguments(
        &self,
        q: &[f64],
        qd: &[f64],
        velocity_gain: f64,
        acceleration: &[f64],
        velocity: &[f64],
    ) -> FlowResult<()> {
        let d = self.config().state_dim;
        check_input("state", d, q)?;
        check_input("velocity", d, qd)?;
        self.check_output(acceleration)?;
        self.check_output(velocity)?;
        if !(velocity_gain.is_finite() && velocity_gain > 0.0) {
            return Err(FlowError::InvalidConfig(
                "velocity gain K_v must be finite and > 0".into(),
            ));
        }
        Ok(())
    }

    /// The command at the measured `(q, q̇)`, with `ws.conditioning` made for the context:
    /// the field is read at the measurement, or at a hold's `reference` `(y, ẏ)`, which is
    /// then tracked: the velocity loop follows `s(q, w) w`, `w = v_des + (K_v/4)(y − q)`,
    /// a pull towards the reference slowed by the joint range's own time scaling at `q`
    /// into the speed and braking bounds. The barrier acts on the measurement either way.
    #[allow(clippy::too_many_arguments)]
    fn acceleration_reading(
        &self,
        q: &[f64],
        qd: &[f64],
        reference: Option<(&[f64], &[f64])>,
        velocity_gain: f64,
        ws: &mut PolicyWorkspace,
        acceleration: &mut [f64],
        velocity: &mut [f64],
    ) -> FlowResult<()> {
        let (y, yd) = reference.unwrap_or((q, qd));
        for ((d, y), yd) in ws.dual.iter_mut().zip(y).zip(yd) {
            *d = Dual::new(*y, *yd);
        }
        self.flow.inverse_recorded_dual(
            &ws.dual,
            &ws.conditioning,
            &mut ws.scratch_dual,
            &mut ws.dual_z,
            &mut ws.dual_tape,
        );
        self.latent.velocity(&ws.dual_z, &mut ws.dual_velocity);
        for ((x, z), v) in ws.dual2.iter_mut().zip(&ws.dual_z).zip(&ws.dual_velocity) {
            *x = Dual::new(*z, *v);
        }
        self.flow.forward_second(
            &ws.dual2,
            &ws.conditioning,
            &ws.dual_tape,
            &mut ws.tangent,
            &mut ws.dual2_y,
        );
        // `(v_des, d/dt v_des)` per joint, in `dual_velocity` (free once the forward pass
        // is done); `dual` still holds the reading `(y, ẏ)`.
        for (v, y) in ws.dual_velocity.iter_mut().zip(&ws.dual2_y) {
            *v = y.du;
        }
        self.limit_speed(&ws.dual, &mut ws.dual_velocity);
        for (i, v_des) in ws.dual_velocity.iter().enumerate() {
            velocity[i] = v_des.re;
        }
        let tracked = &mut ws.tracked_velocity;
        tracked.copy_from_slice(velocity);
        if let (Some(range), Some(_)) = (&self.config().joint_range, reference) {
            let pull = 0.25 * velocity_gain;
            for (w, (y, q)) in tracked.iter_mut().zip(y.iter().zip(q)) {
                *w += pull * (y - q);
            }
            let s = range.speed_scale(q, tracked);
            tracked.iter_mut().for_each(|w| *w *= s);
        }
        for (i, v_des) in ws.dual_velocity.iter().enumerate() {
            acceleration[i] = v_des.du + velocity_gain * (tracked[i] - qd[i]);
        }
        if let Some(range) = &self.config().joint_range {
            let latent_norm = ws.dual_z.iter().map(|z| z.re * z.re).sum::<f64>().sqrt();
            range.limit_acceleration(q, qd, latent_norm, acceleration);
        }
        Ok(())
    }

    /// The go-to attractor `y* = f(0, c)` (`= target(c)` for goal-conditioned tasks).
    pub fn attractor(
        &self,
        context: &[f64],
        ws: &mut PolicyWorkspace,
        out: &mut [f64],
    ) -> FlowResult<()> {
        if !self.latent.kind().is_go_to() {
            return Err(FlowError::InvalidConfig(
                "only go-to policies have a fixed-point attractor".into(),
            ));
        }
        self.check_output(out)?;
        self.flow
            .condition(context, &mut ws.conditioning, &mut ws.scratch)?;
        self.flow
            .forward(&ws.origin, &ws.conditioning, &mut ws.scratch, out);
        Ok(())
    }

    /// Distance (observation units) from `y` to the attractor: to `f(0, c)` for go-to, to
    /// the point `f(π(z), c)` of the orbit with the same phase for limit cycles.
    pub fn attractor_distance(
        &self,
        y: &[f64],
        context: &[f64],
        ws: &mut PolicyWorkspace,
        scratch_point: &mut [f64],
    ) -> FlowResult<f64> {
        self.check_output(scratch_point)?;
        self.invert(y, context, ws)?;
        self.latent.project_onto_attractor(&ws.z, &mut ws.z_next);
        self.flow
            .forward(&ws.z_next, &ws.conditioning, &mut ws.scratch, scratch_point);
        Ok(distance(y, scratch_point))
    }

    /// Exact `log p(y_k | y_{k-1}, c) = log p(z_k | z_{k-1}) + log|det ∂f⁻¹/∂y (y_k)|`,
    /// both states mapped with the same context (see the module docs for which one).
    /// In the data's own units: the normalisation Jacobian is included.
    pub fn log_transition(
        &self,
        y_prev: &[f64],
        y_next: &[f64],
        context: &[f64],
        ws: &mut PolicyWorkspace,
    ) -> FlowResult<f64> {
        let log_det = self.latent_pair(y_prev, y_next, context, ws)?;
        Ok(self.latent.log_transition(&ws.z, &ws.z_later, &mut ws.mean) + log_det)
    }

    /// `log p(y_{k+h} | y_k, c)` of the `horizon`-step model (allocates).
    pub fn log_transition_multi(
        &self,
        y_prev: &[f64],
        y_next: &[f64],
        context: &[f64],
        horizon: usize,
        ws: &mut PolicyWorkspace,
    ) -> FlowResult<f64> {
        let log_det = self.latent_pair(y_prev, y_next, context, ws)?;
        Ok(self
            .latent
            .log_transition_multi(&ws.z, &ws.z_later, horizon)?
            + log_det)
    }

    /// Leaves `z_{k-1}` in `ws.z` and `z_k` in `ws.z_later`; returns
    /// `log|det ∂f⁻¹/∂y (y_k)|`.
    fn latent_pair(
        &self,
        y_prev: &[f64],
        y_next: &[f64],
        context: &[f64],
        ws: &mut PolicyWorkspace,
    ) -> FlowResult<f64> {
        let log_det = self.invert(y_next, context, ws)?;
        std::mem::swap(&mut ws.z, &mut ws.z_later);
        self.invert(y_prev, context, ws)?;
        Ok(log_det)
    }

    /// `log p(y₀ | c₀) = log N(z₀; 0, diag σ₀²) + log|det ∂f⁻¹/∂y (y₀)|`.
    pub fn log_initial(
        &self,
        y0: &[f64],
        context: &[f64],
        ws: &mut PolicyWorkspace,
    ) -> FlowResult<f64> {
        let log_det = self.invert(y0, context, ws)?;
        Ok(self.latent.log_initial(&ws.z) + log_det)
    }
}

#[cfg(test)]
mod tests {
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    use super::*;
    use crate::flow::{CouplingKind, LatentKind};

    /// An engaged hold's reference moves by the latent's exact flow, so it converges to the
    /// attractor however fast the latent contracts: at 300 /s an Euler step of one 10 ms
    /// period (factor `1 − 3`) would overshoot the attractor at every period and swing
    /// about it, held at the speed limit.
    #[test]
    fn an_engaged_reference_converges_however_fast_the_latent_contracts() {
        let mut config = FlowConfig::new(
            "hold",
            3,
            2,
            LatentKind::GoTo,
            CouplingKind::AFFINE,
            4,
            vec![8, 8],
        );
        config.min_rate = 300.0;
        let range = JointRange {
            position_min: vec![-1.0; 3],
            position_max: vec![1.0; 3],
            speed_max: vec![1e3; 3],
            acceleration_max: vec![1e4; 3],
        };
        config.joint_range = Some(range.clone());
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let weights = Weights::random(&config.parameter_shapes(), 0.3, &mut rng);
        let policy = Policy::new(&config, weights).unwrap();
        let mut ws = policy.workspace();
        policy
            .flow
            .condition(&[0.3, -0.2], &mut ws.conditioning, &mut ws.scratch)
            .unwrap();
        let mut hold = EndStopHold::new(3, 0.01).unwrap();
        hold.engaged = true;
        hold.latent.copy_from_slice(&[0.5, -0.3, 0.2]);
        let size = |z: &[f64]| z.iter().map(|v| v * v).sum::<f64>().sqrt();
        for period in 0..20 {
            let before = size(&hold.latent);
            policy.step_reference(&range, &mut hold, &mut ws);
            let after = size(&hold.latent);
            assert!(after < before, "period {period}: {before} -> {after}");
        }
        assert!(size(&hold.latent) < 1e-12, "{:?}", hold.latent);
    }

    /// `act` shares one forward sweep between the mean step and the velocity; it must give
    /// what `mean_next` and `velocity` give separately.
    #[test]
    fn act_is_the_mean_next_state_and_the_desired_velocity() {
        let couplings = [
            CouplingKind::AFFINE,
            CouplingKind::Affine {
                scale_bound: 2.0,
                taper_radius: Some(1.5),
            },
            CouplingKind::Spline {
                bins: 8,
                tail_bound: 3.0,
            },
        ];
        for (k, coupling) in couplings.into_iter().enumerate() {
            for latent in [
                LatentKind::GoTo,
                LatentKind::SaturatedGoTo,
                LatentKind::LimitCycle,
            ] {
                let mut config =
                    FlowConfig::new("act", 5, 3, latent, coupling.clone(), 4, vec![19, 33]);
                if latent.is_go_to() {
                    config.goal_context_indices = Some(vec![2, 0, 1, 2, 0]);
                }
                let mut rng = ChaCha8Rng::seed_from_u64(k as u64);
                let weights = Weights::random(&config.parameter_shapes(), 1.0, &mut rng);
                let policy = Policy::new(&config, weights).unwrap();
                let mut ws = policy.workspace();
                let y = [0.3, -1.2, 0.8, 2.5, -0.4];
                let context = [0.2, -0.7, 0.5];
                let (mut next, mut velocity) = ([0.0; 5], [0.0; 5]);
                let (mut expected_next, mut expected_velocity) = ([0.0; 5], [0.0; 5]);
                policy
                    .act(&y, &context, &mut ws, &mut next, &mut velocity)
                    .unwrap();
                policy
                    .mean_next(&y, &context, &mut ws, &mut expected_next)
                    .unwrap();
                policy
                    .velocity(&y, &context, &mut ws, &mut expected_velocity)
                    .unwrap();
                for (a, b) in next.iter().zip(&expected_next) {
                    assert!((a - b).abs() < 1e-12 * (1.0 + b.abs()), "{a} vs {b}");
                }
                for (a, b) in velocity.iter().zip(&expected_velocity) {
                    assert!((a - b).abs() < 1e-12 * (1.0 + b.abs()), "{a} vs {b}");
                }
                assert!(velocity.iter().any(|v| v.abs() > 1e-3));
            }
        }
    }
}
