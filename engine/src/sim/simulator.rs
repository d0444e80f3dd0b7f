//! The simulator: computed-torque control at `control_dt`, physics at `physics_dt`.

use serde::{Deserialize, Serialize};

use super::integrator::Stages;
use super::{Perturbation, PerturbationKind, SimConfig, SimError};
use crate::algorithm::check_vector;
use crate::control::{ComputedTorque, JointMask, Saturation};
use crate::math::{DVector, Real, Vector3};
use crate::robot::Robot;

/// What happened during one control period. The torque command applied over it (after
/// the limits) is the controller's [`command`](ComputedTorque::command); it is not copied
/// here, since a step of thousands of batched environments would allocate for it each.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StepReport {
    /// Which joints the torque and rate limits changed.
    pub saturation: Saturation,
    /// Joints that touched an end stop during the period.
    pub end_stops: JointMask,
    /// Joints whose speed exceeded `qd_max` at the end of the period (reported only).
    pub over_speed: JointMask,
    /// Simulated time after the step, s.
    pub time: Real,
}

/// Simulates `M(q) q̈ + C(q, q̇) q̇ + g(q) = τ + τ_ext` for a boxed [`Robot`].
///
/// - Control: every `control_dt`, [`Simulator::step`] turns `q̈_des` into a torque with
///   [`ComputedTorque`] from the state at that instant; the torque is held (zero-order
///   hold) for the `control_dt / physics_dt` physics substeps.
/// - Perturbations: `τ_ext(t, q)` is evaluated at every integrator stage, so it acts
///   within the control period; it enters only the physics, never the controller.
/// - End stops: after each substep a joint beyond `[q_min, q_max]` is put back on the stop
///   and its outward velocity set to zero (a perfectly inelastic stop), and reported.
///
/// With one substep, no active limit and the default integrator, the velocity update is
/// exactly `q̇ ← q̇ + h (q̈_des + M⁻¹ τ_ext)`. All buffers are allocated in
/// [`Simulator::new`]; a step allocates only the returned report.
#[derive(Debug)]
pub struct Simulator {
    robot: Box<dyn Robot>,
    config: SimConfig,
    substeps: usize,
    controller: ComputedTorque,
    perturbations: Vec<Perturbation>,
    q: DVector,
    qd: DVector,
    step_count: u64,
    stages: Stages,
    tau_total: DVector,
    tau_link: DVector,
    /// Whether any joint has a finite position limit, and a finite speed limit: an
    /// infinite one never acts, so a robot without any (the point masses) skips the
    /// checks and the reads of its limits at every substep. Read once: the `Robot` trait
    /// has no way to change a boxed robot's limits.
    has_end_stops: bool,
    has_speed_limits: bool,
}

impl Simulator {
    /// Checks the configuration and the robot's limits; the state starts at `q = 0`
    /// (clamped into the limits), `q̇ = 0`.
    pub fn new(robot: Box<dyn Robot>, config: SimConfig) -> Result<Self, SimError> {
        let substeps = config.substeps()?;
        let dof = robot.dof();
        robot.limits().validate(dof)?;
        let limits = robot.limits();
        let q0: DVector =
            DVector::from_fn(dof, |i, _| 0.0_f64.clamp(limits.q_min[i], limits.q_max[i]));
        let finite = |bounds: &DVector| bounds.iter().any(|b| b.is_finite());
        let has_end_stops = finite(&limits.q_min) || finite(&limits.q_max);
        let has_speed_limits = finite(&limits.qd_max);
        let mut simulator = Self {
            controller: ComputedTorque::new(dof, config.control_dt)?,
            robot,
            config,
            substeps,
            perturbations: Vec::new(),
            q: DVector::zeros(dof),
            qd: DVector::zeros(dof),
            step_count: 0,
            stages: Stages::new(dof),
            tau_total: DVector::zeros(dof),
            tau_link: DVector::zeros(dof),
            has_end_stops,
            has_speed_limits,
        };
        simulator.reset(q0.as_slice(), &vec![0.0; dof])?;
        Ok(simulator)
    }

    /// Sets the state, time 0, and starts the torque-rate limiter from `g(q₀)`. Clears
    /// the perturbations. `q0` must lie within the joint limits.
    pub fn reset(&mut self, q0: &[Real], qd0: &[Real]) -> Result<(), SimError> {
        let dof = self.robot.dof();
        check_vector("q0", q0, dof)?;
        check_vector("qd0", qd0, dof)?;
        let limits = self.robot.limits();
        for (joint, &value) in q0.iter().enumerate() {
            let (min, max) = (limits.q_min[joint], limits.q_max[joint]);
            if !(min..=max).contains(&value) {
                return Err(SimError::OutsideLimits {
                    joint,
                    value,
                    min,
                    max,
                });
            }
        }
        self.controller.reset(self.robot.as_mut(), q0)?;
        self.q.copy_from_slice(q0);
        self.qd.copy_from_slice(qd0);
        self.step_count = 0;
        self.perturbations.clear();
        Ok(())
    }

    /// Schedules a perturbation (absolute simulated time). Checked: finite start,
    /// non-negative duration, a window that still acts (not empty, not over by now),
    /// dimension, link index and finite values.
    pub fn perturb(&mut self, perturbation: Perturbation) -> Result<(), SimError> {
        let invalid = |reason: String| Err(SimError::InvalidPerturbation(reason));
        let Perturbation {
            start, duration, ..
        } = perturbation;
        if !start.is_finite() || duration.is_nan() || duration < 0.0 {
            return invalid(format!(
                "start {start} must be finite and duration {duration} non-negative"
            ));
        }
        // A push that can no longer act is a mistake (a start in the wrong unit or time
        // base), not a request to do nothing.
        let (end, now) = (start + duration, self.time());
        if duration == 0.0 {
            return invalid(format!(
                "a duration of 0 s never acts (window [{start}, {end}) s)"
            ));
        }
        if end <= now {
            return invalid(format!(
                "its window [{start}, {end}) s is over: the simulated time is {now} s"
            ));
        }
        match &perturbation.kind {
            PerturbationKind::JointTorque(tau) => {
                check_vector("joint torque", tau, self.robot.dof())?
            }
            PerturbationKind::LinkWrench {
                link,
                force,
                torque,
            } => {
                if *link >= self.robot.link_count() {
                    return invalid(format!(
                        "link {link} does not exist ({} movable links)",
                        self.robot.link_count()
                    ));
                }
                check_vector("force", force, 3)?;
                check_vector("torque", torque, 3)?;
            }
        }
        self.perturbations.push(perturbation);
        Ok(())
    }

    pub fn perturbations(&self) -> &[Perturbation] {
        &self.perturbations
    }

    /// Whether an external force acted during the last control period: its motion then
    /// shows the disturbance, not the controller's command alone.
    pub fn perturbed(&self) -> bool {
        let now = self.time();
        let from = now - self.config.control_dt;
        self.perturbations.iter().any(|p| p.overlaps(from, now))
    }

    pub fn clear_perturbations(&mut self) {
        self.perturbations.clear();
    }

    /// One control period driven by the desired joint accelerations `q̈_des`.
    pub fn step(&mut self, qdd_desired: &[Real]) -> Result<StepReport, SimError> {
        // Among thousands of environments this one's workspace has left the cache.
        self.robot.prefetch_workspace();
        let saturation = self.controller.compute(
            self.robot.as_mut(),
            self.q.as_slice(),
            self.qd.as_slice(),
            qdd_desired,
        )?;
        self.advance(saturation)
    }

    /// One control period with the joint torque `τ` applied as given (open loop, no torque
    /// limits); the computed-torque rate limiter continues from `τ`.
    pub fn step_torque(&mut self, tau: &[Real]) -> Result<StepReport, SimError> {
        self.robot.prefetch_workspace();
        self.controller.hold(tau)?;
        self.advance(Saturation::default())
    }

    fn advance(&mut self, saturation: Saturation) -> Result<StepReport, SimError> {
        let mut end_stops = JointMask::empty();
        let h = self.config.physics_dt;
        for _ in 0..self.substeps {
            let time = self.time();
            let Self {
                robot,
                perturbations,
                controller,
                tau_total,
                tau_link,
                ..
            } = self;
            let tau = controller.command();
            self.config.integrator.step(
                &mut self.stages,
                time,
                h,
                &mut self.q,
                &mut self.qd,
                |t, q, qd, qdd| {
                    tau_total.copy_from(tau);
                    for perturbation in perturbations.iter().filter(|p| p.is_active(t)) {
                        match &perturbation.kind {
                            PerturbationKind::JointTorque(tau_ext) => {
                                for (total, ext) in tau_total.iter_mut().zip(tau_ext) {
                                    *total += ext;
                                }
                            }
                            PerturbationKind::LinkWrench {
                                link,
                                force,
                                torque,
                            } => {
                                robot.wrench_to_joint_torque(
                                    q.as_slice(),
                                    *link,
                                    &Vector3::from(*force),
                                    &Vector3::from(*torque),
                                    tau_link,
                                )?;
                                *tau_total += &*tau_link;
                            }
                        }
                    }
                    robot.forward_dynamics(q.as_slice(), qd.as_slice(), tau_total.as_slice(), qdd)
                },
            )?;
            self.step_count += 1;
            if self.has_end_stops {
                end_stops = end_stops.union(self.apply_end_stops());
            }
            if !(self.q.iter().chain(self.qd.iter()).all(|x| x.is_finite())) {
                return Err(SimError::NonFiniteState { time: self.time() });
            }
        }
        let mut over_speed = JointMask::empty();
        if self.has_speed_limits {
            let qd_max = &self.robot.limits().qd_max;
            for (i, (qd, max)) in self.qd.iter().zip(qd_max.iter()).enumerate() {
                if qd.abs() > *max {
                    over_speed.insert(i);
                }
            }
        }
        Ok(StepReport {
            saturation,
            end_stops,
            over_speed,
            time: self.time(),
        })
    }

    /// Inelastic end stops: `q ← clamp(q)`, outward `q̇ ← 0`.
    fn apply_end_stops(&mut self) -> JointMask {
        let limits = self.robot.limits();
        let mut hit = JointMask::empty();
        for i in 0..self.q.len() {
            if self.q[i] < limits.q_min[i] {
                self.q[i] = limits.q_min[i];
                self.qd[i] = self.qd[i].max(0.0);
                hit.insert(i);
            } else if self.q[i] > limits.q_max[i] {
                self.q[i] = limits.q_max[i];
                self.qd[i] = self.qd[i].min(0.0);
                hit.insert(i);
            }
        }
        hit
    }

    pub fn q(&self) -> &DVector {
        &self.q
    }

    pub fn qd(&self) -> &DVector {
        &self.qd
    }

    /// Simulated time, s (a whole number of physics steps since the last reset).
    pub fn time(&self) -> Real {
        self.step_count as Real * self.config.physics_dt
    }

    pub fn config(&self) -> &SimConfig {
        &self.config
    }

    pub fn robot(&self) -> &dyn Robot {
        self.robot.as_ref()
    }

    /// Mutable access for dynamics queries (the robot holds no simulation state).
    pub fn robot_mut(&mut self) -> &mut dyn Robot {
        self.robot.as_mut()
    }

    /// The controller, e.g. for its last command (the torque applied over the last period)
    /// or its last request before the limits.
    pub fn controller(&self) -> &ComputedTorque {
        &self.controller
    }
}
