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

    /// `S` in the frame `placement` maps the child body frame to, `placement.act_motion(S)`,
    /// without the products by `S`'s zero half: `(p × R a, R a)` (revolute) or `(R a, 0)`
    /// (prismatic), with `R a` a column of `R` for an axis along z.
    #[inline(always)]
    pub(crate) fn motion_subspace_in(&self, placement: &Se3) -> Motion {
        let r = &placement.rotation;
        let axis = if self.axis == Vector3::z() {
            r.column(2).into_owned()
        } else {
            r * self.axis
        };
        match self.kind {
            JointKind::Revolute => Motion::new(placement.translation.cross(&axis), axis),
            JointKind::Prismatic => Motion::new(axis, Vector3::zeros()),
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The shortcut against the full motion transform, for each of its three branches.
    #[test]
    fn motion_subspace_in_a_frame_is_the_transformed_subspace() {
        let placement = Se3::new(
            Se3::rotation_about(&Vector3::new(0.3, -0.5, 0.8).normalize(), 1.1),
            Vector3::new(0.2, -0.4, 0.7),
        );
        let tilted = Vector3::new(0.6, 0.0, -0.8);
        for joint in [
            Joint::revolute("z", Se3::identity(), Vector3::z()),
            Joint::revolute("tilted", Se3::identity(), tilted),
            Joint::prismatic("slide", Se3::identity(), tilted),
        ] {
            let expected = placement.act_motion(&joint.motion_subspace());
            let error = (joint.motion_subspace_in(&placement) - expected)
                .to_vector6()
                .amax();
            assert!(error < 1e-15, "{}: off by {error}", joint.name);
        }
    }
}
