//! A point mass moving in a horizontal plane.

use std::sync::{Arc, LazyLock};

use super::{DynamicsError, Frame, JointLimits, Robot};
use crate::algorithm::{check_len, check_matrix_shape, check_vector};
use crate::math::{DMatrix, DVector, Isometry3, Real, Vector3};
use crate::model::ModelError;
use crate::spatial::Se3;

const DOF: usize = 2;
const MASS_LINK: usize = 0;
const MASS_FRAME: usize = 1;

static UNLIMITED: LazyLock<Arc<JointLimits>> =
    LazyLock::new(|| Arc::new(JointLimits::unlimited(DOF)));

/// A point mass `m` at `q = (x, y)` in a horizontal plane: `M = m 1₂`, `C = 0`, `g = 0`,
/// so `m q̈ = τ + τ_ext` with `τ` the planar force. Frames: 0 the plane, 1 the mass.
/// An external wrench acts through its in-plane force `(f_x, f_y)` only; the plane takes
/// the rest.
#[derive(Clone, Debug)]
pub struct PointMass2d {
    mass: Real,
    /// Shared: every point mass without limits reads the same (infinite) ones, so the
    /// thousands of a batched session keep one copy in cache, not one each.
    limits: Arc<JointLimits>,
    frames: [Frame; 2],
}

impl PointMass2d {
    /// A mass of `mass` kg without limits.
    pub fn new(mass: Real) -> Result<Self, ModelError> {
        if !(mass.is_finite() && mass > 0.0) {
            return Err(ModelError::InvalidInertia {
                body: "mass".into(),
                reason: "the mass must be finite and positive",
            });
        }
        Ok(Self {
            mass,
            limits: Arc::clone(&UNLIMITED),
            frames: [
                Frame {
                    name: "plane".into(),
                    body: None,
                    placement: Se3::identity(),
                },
                Frame {
                    name: "mass".into(),
                    body: Some(MASS_LINK),
                    placement: Se3::identity(),
                },
            ],
        })
    }

    /// Sets position, velocity, acceleration and force limits (defaults: unlimited).
    pub fn with_limits(mut self, limits: JointLimits) -> Result<Self, ModelError> {
        limits.validate(DOF)?;
        self.limits = Arc::new(limits);
        Ok(self)
    }

    pub fn mass(&self) -> Real {
        self.mass
    }

    fn check_frame(&self, frame: usize) -> Result<(), DynamicsError> {
        if frame < self.frames.len() {
            Ok(())
        } else {
            Err(DynamicsError::NoSuchFrame {
                index: frame,
                count: self.frames.len(),
            })
        }
    }
}

/// Fills `out` with zeros after checking its length.
fn zero_vector(quantity: &'static str, out: &mut DVector) -> Result<(), DynamicsError> {
    check_len(quantity, out.len(), DOF)?;
    out.fill(0.0);
    Ok(())
}

impl Robot for PointMass2d {
    fn name(&self) -> &str {
        "point_mass_2d"
    }

    fn dof(&self) -> usize {
        DOF
    }

    fn limits(&self) -> &JointLimits {
        &self.limits
    }

    fn frames(&self) -> &[Frame] {
        &self.frames
    }

    fn end_effector(&self) -> usize {
        MASS_FRAME
    }

    fn link_count(&self) -> usize {
        1
    }

    fn frame_placement(&self, q: &[Real], frame: usize) -> Result<Isometry3, DynamicsError> {
        check_vector("q", q, DOF)?;
        self.check_frame(frame)?;
        let position = if frame == MASS_FRAME {
            Vector3::new(q[0], q[1], 0.0)
        } else {
            Vector3::zeros()
        };
        Ok(Isometry3::translation(position.x, position.y, position.z))
    }

    fn frame_jacobian(
        &self,
        q: &[Real],
        frame: usize,
        point: &Vector3,
        jacobian: &mut DMatrix,
    ) -> Result<(), DynamicsError> {
        check_vector("q", q, DOF)?;
        check_vector("point", point.as_slice(), 3)?;
        self.check_frame(frame)?;
        check_matrix_shape("jacobian", jacobian, 6, DOF)?;
        jacobian.fill(0.0);
        if frame == MASS_FRAME {
            jacobian[(0, 0)] = 1.0;
            jacobian[(1, 1)] = 1.0;
        }
        Ok(())
    }

    fn wrench_to_joint_torque(
        &self,
        q: &[Real],
        link: usize,
        force: &Vector3,
        torque: &Vector3,
        tau: &mut DVector,
    ) -> Result<(), DynamicsError> {
        check_vector("q", q, DOF)?;
        check_vector("force", force.as_slice(), 3)?;
        check_vector("torque", torque.as_slice(), 3)?;
        check_len("tau", tau.len(), DOF)?;
        if link != MASS_LINK {
            return Err(DynamicsError::NoSuchLink {
                index: link,
                count: 1,
            });
        }
        tau[0] = force.x;
        tau[1] = force.y;
        Ok(())
    }

    fn mass_matrix(&mut self, q: &[Real], m: &mut DMatrix) -> Result<(), DynamicsError> {
        check_vector("q", q, DOF)?;
        check_matrix_shape("m", m, DOF, DOF)?;
        m.fill_with_identity();
        *m *= self.mass;
        Ok(())
    }

    fn gravity(&mut self, q: &[Real], g: &mut DVector) -> Result<(), DynamicsError> {
        check_vector("q", q, DOF)?;
        zero_vector("g", g)
    }

    fn coriolis_matrix(
        &mut self,
        q: &[Real],
        qd: &[Real],
        c: &mut DMatrix,
    ) -> Result<(), DynamicsError> {
        check_vector("q", q, DOF)?;
        check_vector("qd", qd, DOF)?;
        check_matrix_shape("c", c, DOF, DOF)?;
        c.fill(0.0);
        Ok(())
    }

    fn nonlinear_effects(
        &mut self,
        q: &[Real],
        qd: &[Real],
        nle: &mut DVector,
    ) -> Result<(), DynamicsError> {
        check_vector("q", q, DOF)?;
        check_vector("qd", qd, DOF)?;
        zero_vector("nle", nle)
    }

    fn inverse_dynamics(
        &mut self,
        q: &[Real],
        qd: &[Real],
        qdd: &[Real],
        tau: &mut DVector,
    ) -> Result<(), DynamicsError> {
        check_vector("q", q, DOF)?;
        check_vector("qd", qd, DOF)?;
        check_vector("qdd", qdd, DOF)?;
        check_len("tau", tau.len(), DOF)?;
        for (tau, qdd) in tau.iter_mut().zip(qdd) {
            *tau = self.mass * qdd;
        }
        Ok(())
    }

    fn forward_dynamics(
        &mut self,
        q: &[Real],
        qd: &[Real],
        tau: &[Real],
        qdd: &mut DVector,
    ) -> Result<(), DynamicsError> {
        check_vector("q", q, DOF)?;
        check_vector("qd", qd, DOF)?;
        check_vector("tau", tau, DOF)?;
        check_len("qdd", qdd.len(), DOF)?;
        for (qdd, tau) in qdd.iter_mut().zip(tau) {
            *qdd = tau / self.mass;
        }
        Ok(())
    }

    fn boxed_clone(&self) -> Box<dyn Robot> {
        Box::new(self.clone())
    }
}
