//! Revolute joints.

use crate::math::{Matrix3, Real, Vector3};
use crate::spatial::{Motion, Se3};

/// A revolute joint: the joint frame sits at `placement` in the parent body's frame (at
/// `q = 0`) and rotates about the unit `axis` (joint-frame coordinates), so that
/// `ᵖMᵢ(q) = placement · Rot(axis, q)`.
#[derive(Clone, Debug, PartialEq)]
pub struct RevoluteJoint {
    pub name: String,
    pub placement: Se3,
    pub axis: Vector3,
}

impl RevoluteJoint {
    /// The placement `ᵖMᵢ(q)` of the child body in its parent.
    pub fn transform(&self, q: Real) -> Se3 {
        let rotation = if self.axis == Vector3::z() {
            // The common case (DH chains, most URDFs): `R Rz(q)` mixes two columns.
            let (s, c) = q.sin_cos();
            let r = &self.placement.rotation;
            let (x, y) = (r.column(0), r.column(1));
            Matrix3::from_columns(&[x * c + y * s, y * c - x * s, r.column(2).into_owned()])
        } else {
            self.placement.rotation * Se3::rotation_about(&self.axis, q)
        };
        Se3::new(rotation, self.placement.translation)
    }

    /// The motion subspace `S = (0, axis)` in the child body frame: `vᵢ = S q̇ᵢ`.
    pub fn motion_subspace(&self) -> Motion {
        Motion::new(Vector3::zeros(), self.axis)
    }
}
