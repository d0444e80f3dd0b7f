//! One-degree-of-freedom joints: revolute (an angle about an axis) and prismatic (a
//! displacement along it).

use crate::math::{Matrix3, Real, Vector3, sin_cos};
use crate::spatial::{Force, Motion, Se3};

/// How a joint moves its child along its unit axis.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum JointKind {
    /// `q` is an angle (rad) about the axis.
    Revolute,
    /// `q` is a displacement (m) along the axis.
    Prismatic,
}

/// A joint: the joint frame sits at `placement` in the parent body's frame (at `q = 0`)
/// and moves along the unit `axis` (joint-frame coordinates), so that
/// `ᵖMᵢ(q) = placement · Rot(axis, q)` (revolute) or `placement · Trans(axis q)`
/// (prismatic).
#[derive(Clone, Debug, PartialEq)]
pub struct Joint {
    pub name: String,
    pub kind: JointKind,
    pub placement: Se3,
    pub axis: Vector3,
}

impl Joint {
    pub fn revolute(name: impl Into<String>, placement: Se3, axis: Vector3) -> Self {
        Self {
            name: name.into(),
            kind: JointKind::Revolute,
            placement,
            axis,
        }
    }

    pub fn prismatic(name: impl Into<String>, placement: Se3, axis: Vector3) -> Self {
        Self {
            name: name.into(),
            kind: JointKind::Prismatic,
            placement,
            axis,
        }
    }

    /// The placement `ᵖMᵢ(q)` of the child body in its parent.
    pub fn transform(&self, q: Real) -> Se3 {
        let (sin, cos) = sin_cos(q);
        self.transform_from(q, sin, cos)
    }

    /// [`transform`](Self::transform) with `sin q` and `cos q` already computed (a
    /// prismatic joint ignores them), so that the algorithms can take the sines and
    /// cosines of all joints at once.
    #[inline(always)]
    pub(crate) fn transform_from(&self, q: Real, sin: Real, cos: Real) -> Se3 {
        let placement = &self.placement;
        match self.kind {
            JointKind::Prismatic => Se3::new(
                placement.rotation,
                placement.translation + placement.rotation * (self.axis * q),
            ),
            JointKind::Revolute if self.axis == Vector3::z() => {
                // The common case (DH chains, most URDFs): `R Rz(q)` mixes two columns.
                let r = &placement.rotation;
                let (x, y) = (r.column(0), r.column(1));
                let rotation = Matrix3::from_columns(&[
                    x * cos + y * sin,
                    y * cos - x * sin,
                    r.column(2).into_owned(),
                ]);
                Se3::new(rotation, placement.translation)
            }
            JointKind::Revolute => Se3::new(
                placement.rotation * Se3::rotation_about_from(&self.axis, sin, cos),
                placement.translation,
            ),
        }
    }

    /// The motion subspace `S` in the child body frame, `vᵢ = S q̇ᵢ`: `(0, axis)` for a
    /// revolute joint, `(axis, 0)` for a prismatic one (`(linear, angular)` order).
    pub fn motion_subspace(&self) -> Motion {
        match self.kind {
            JointKind::Revolute => Motion::new(Vector3::zeros(), self.axis),
            JointKind::Prismatic => Motion::new(self.axis, Vector3::zeros()),
        }
    }

    /// `Sᵀ f`: the joint's share of a wrench given in the child body frame — the torque
    /// about the axis (revolute) or the force along it (prismatic).
    pub fn project(&self, wrench: &Force) -> Real {
        match self.kind {
            JointKind::Revolute => self.axis.dot(&wrench.angular),
            JointKind::Prismatic => self.axis.dot(&wrench.linear),
        }
    }
}
