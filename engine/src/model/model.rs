//! The read-only description of a serial chain.

use super::{Frame, Joint, JointKind, JointLimits, ModelError};
use crate::math::{DVector, Real, Vector3};
use crate::spatial::{AxisAlignedRotation, Inertia, Se3};

/// Standard gravity along `−z` of the base frame (Pinocchio's default), m/s².
pub const STANDARD_GRAVITY: Real = 9.81;
/// The name a wrong number of armature entries is reported under
/// ([`ModelError::Dimension`]).
pub const ARMATURE: &str = "armature";

/// One movable body: the joint that moves it and its spatial inertia in its own frame.
#[derive(Clone, Debug, PartialEq)]
pub struct Body {
    pub name: String,
    pub joint: Joint,
    pub inertia: Inertia,
}

/// A serial chain `base → body 0 → … → body n−1` of revolute and prismatic joints.
///
/// Frames: index 0 is the base, index `i + 1` the frame of body `i`, then the extra frames
/// given to [`Model::new`] (flange, hand, …).
#[derive(Clone, Debug, PartialEq)]
pub struct Model {
    name: String,
    gravity: Vector3,
    bodies: Vec<Body>,
    frames: Vec<Frame>,
    limits: JointLimits,
    armature: DVector,
    /// See [`Model::axis_aligned_placements`].
    axis_aligned_placements: Option<Vec<AxisAlignedRotation>>,
}

impl Model {
    /// Checks the chain (finite numbers, non-zero axes which get normalised, physically
    /// valid inertias, unique frame names); gravity is `(0, 0, −9.81)`, limits unlimited.
    pub fn new(
        name: impl Into<String>,
        base_name: impl Into<String>,
        mut bodies: Vec<Body>,
        extra_frames: Vec<Frame>,
    ) -> Result<Self, ModelError> {
        for body in &mut bodies {
            validate_body(body)?;
        }
        let mut frames = Vec::with_capacity(1 + bodies.len() + extra_frames.len());
        frames.push(Frame {
            name: base_name.into(),
            body: None,
            placement: Se3::identity(),
        });
        frames.extend(bodies.iter().enumerate().map(|(i, body)| Frame {
            name: body.name.clone(),
            body: Some(i),
            placement: Se3::identity(),
        }));
        for frame in extra_frames {
            if let Some(body) = frame.body.filter(|&b| b >= bodies.len()) {
                return Err(ModelError::NoSuchBody {
                    frame: frame.name,
                    body,
                    bodies: bodies.len(),
                });
            }
            check_finite_se3(&frame.placement, &frame.name)?;
            frames.push(frame);
        }
        for (i, frame) in frames.iter().enumerate() {
            if frames[..i].iter().any(|other| other.name == frame.name) {
                return Err(ModelError::DuplicateFrame(frame.name.clone()));
            }
        }
        Ok(Self {
            name: name.into(),
            gravity: Vector3::new(0.0, 0.0, -STANDARD_GRAVITY),
            limits: JointLimits::unlimited(bodies.len()),
            armature: DVector::zeros(bodies.len()),
            axis_aligned_placements: axis_aligned_placements(&bodies),
            bodies,
            frames,
        })
    }

    pub fn name(&self) -> &str {
        &self.name
    }

    /// Number of joints (degrees of freedom).
    pub fn nv(&self) -> usize {
        self.bodies.len()
    }

    pub fn bodies(&self) -> &[Body] {
        &self.bodies
    }

    /// The rotations of the joints' placements, when every joint turns about its own z
    /// axis and every placement's rotation maps axes onto axes (Denavit–Hartenberg-style
    /// chains such as the Panda and the UR5e): the CRBA then works in the joints' frames.
    pub fn axis_aligned_placements(&self) -> Option<&[AxisAlignedRotation]> {
        self.axis_aligned_placements.as_deref()
    }

    pub fn frames(&self) -> &[Frame] {
        &self.frames
    }

    pub fn frame_index(&self, name: &str) -> Option<usize> {
        self.frames.iter().position(|f| f.name == name)
    }

    /// Gravity acceleration in the base frame.
    pub fn gravity(&self) -> Vector3 {
        self.gravity
    }

    pub fn limits(&self) -> &JointLimits {
        &self.limits
    }

    pub fn set_limits(&mut self, limits: JointLimits) -> Result<(), ModelError> {
        limits.validate(self.nv())?;
        self.limits = limits;
        Ok(())
    }

    /// Reflected rotor inertias `I_a` (kg·m²), one per joint: the motor's rotor turning
    /// with the joint through its gearbox (`I_rotor · gear_ratio²`). They add `diag(I_a)` to
    /// `M(q)` and `I_a ⊙ q̈` to the inverse dynamics; the rotors' gyroscopic terms are
    /// neglected (Pinocchio's `model.armature`, MuJoCo's `armature`). Zero by default.
    pub fn armature(&self) -> &DVector {
        &self.armature
    }

    /// Sets [`armature`](Self::armature): one finite, non-negative entry per joint.
    pub fn set_armature(&mut self, armature: DVector) -> Result<(), ModelError> {
        if armature.len() != self.nv() {
            return Err(ModelError::Dimension {
                what: ARMATURE,
                expected: self.nv(),
                actual: armature.len(),
            });
        }
        if let Some(joint) = armature.iter().position(|a| !(a.is_finite() && *a >= 0.0)) {
            return Err(ModelError::InvalidArmature {
                joint,
                reason: "must be finite and >= 0",
            });
        }
        self.armature = armature;
        Ok(())
    }

    pub fn set_gravity(&mut self, gravity: Vector3) -> Result<(), ModelError> {
        if !gravity.iter().all(|g| g.is_finite()) {
            return Err(ModelError::NonFinite {
                what: "gravity".into(),
            });
        }
        self.gravity = gravity;
        Ok(())
    }
}

/// [`Model::axis_aligned_placements`] of a chain, `None` as soon as one joint does not fit.
fn axis_aligned_placements(bodies: &[Body]) -> Option<Vec<AxisAlignedRotation>> {
    bodies
        .iter()
        .map(|body| {
            let joint = &body.joint;
            let about_z = joint.kind == JointKind::Revolute && joint.axis == Vector3::z();
            about_z
                .then(|| AxisAlignedRotation::from_matrix(&joint.placement.rotation))
                .flatten()
        })
        .collect()
}

fn validate_body(body: &mut Body) -> Result<(), ModelError> {
    check_finite_se3(&body.joint.placement, &body.joint.name)?;
    let axis = body.joint.axis;
    if !axis.iter().all(|a| a.is_finite()) {
        return Err(ModelError::NonFinite {
            what: format!("axis of joint `{}`", body.joint.name),
        });
    }
    let norm = axis.norm();
    if norm < 1e-12 {
        return Err(ModelError::ZeroAxis {
            joint: body.joint.name.clone(),
        });
    }
    body.joint.axis = axis / norm;
    let inertia = &body.inertia;
    let finite = inertia.mass.is_finite()
        && inertia.first_moment.iter().all(|x| x.is_finite())
        && inertia.rotational.iter().all(|x| x.is_finite());
    let invalid = |reason| ModelError::InvalidInertia {
        body: body.name.clone(),
        reason,
    };
    if !finite {
        return Err(invalid("non-finite entries"));
    }
    if inertia.mass < 0.0 {
        return Err(invalid("negative mass"));
    }
    let eigen = inertia.inertia_com().symmetric_eigenvalues();
    let scale = eigen.amax().max(1e-12);
    if eigen.min() < -1e-9 * scale {
        return Err(invalid(
            "rotational inertia about the centre of mass is not positive semi-definite",
        ));
    }
    Ok(())
}

fn check_finite_se3(placement: &Se3, owner: &str) -> Result<(), ModelError> {
    let finite = placement.rotation.iter().all(|x| x.is_finite())
        && placement.translation.iter().all(|x| x.is_finite());
    if finite {
        Ok(())
    } else {
        Err(ModelError::NonFinite {
            what: format!("placement of `{owner}`"),
        })
    }
}
