//! Spatial motion vectors (twists).

use std::ops::{Add, AddAssign, Mul, Sub};

use super::Force;
use crate::math::{Matrix6, Real, Vector3, Vector6, skew};

/// A spatial motion vector `m = (v, ω)`: the linear velocity `v` of the point at the frame
/// origin and the angular velocity `ω`, both in the frame's axes.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Motion {
    pub linear: Vector3,
    pub angular: Vector3,
}

impl Motion {
    pub const fn new(linear: Vector3, angular: Vector3) -> Self {
        Self { linear, angular }
    }

    pub fn zero() -> Self {
        Self::default()
    }

    /// Motion cross product `m₁ × m₂ = (ω₁ × v₂ + v₁ × ω₂, ω₁ × ω₂)`: the rate of change
    /// of `m₂` seen from a frame moving with `m₁`.
    pub fn cross(&self, other: &Motion) -> Motion {
        Motion {
            linear: self.angular.cross(&other.linear) + self.linear.cross(&other.angular),
            angular: self.angular.cross(&other.angular),
        }
    }

    /// Dual cross product `m ×* f = (ω × f, ω × n + v × f)`, as in the gyroscopic term
    /// `v ×* I v` of the Newton–Euler equations.
    pub fn cross_force(&self, force: &Force) -> Force {
        Force {
            linear: self.angular.cross(&force.linear),
            angular: self.angular.cross(&force.angular) + self.linear.cross(&force.linear),
        }
    }

    /// The matrix `(m ×)` with `(m ×) x = m × x`, in `[linear; angular]` ordering.
    pub fn cross_matrix(&self) -> Matrix6 {
        let mut out = Matrix6::zeros();
        let w = skew(&self.angular);
        out.fixed_view_mut::<3, 3>(0, 0).copy_from(&w);
        out.fixed_view_mut::<3, 3>(0, 3)
            .copy_from(&skew(&self.linear));
        out.fixed_view_mut::<3, 3>(3, 3).copy_from(&w);
        out
    }

    /// The matrix `(m ×*) = −(m ×)ᵀ` with `(m ×*) f = m ×* f`.
    pub fn cross_force_matrix(&self) -> Matrix6 {
        -self.cross_matrix().transpose()
    }

    /// `[linear; angular]` as a 6-vector.
    pub fn to_vector6(&self) -> Vector6 {
        Vector6::new(
            self.linear.x,
            self.linear.y,
            self.linear.z,
            self.angular.x,
            self.angular.y,
            self.angular.z,
        )
    }
}

/// The pairing of the two spaces lives here, beside the motion's action on forces, so
/// that forces need nothing of motions.
impl Force {
    /// The power `mᵀ f = v · f + ω · n` of this wrench on a motion.
    pub fn dot(&self, motion: &Motion) -> Real {
        self.linear.dot(&motion.linear) + self.angular.dot(&motion.angular)
    }
}

impl Add for Motion {
    type Output = Motion;
    fn add(self, rhs: Motion) -> Motion {
        Motion::new(self.linear + rhs.linear, self.angular + rhs.angular)
    }
}

impl Sub for Motion {
    type Output = Motion;
    fn sub(self, rhs: Motion) -> Motion {
        Motion::new(self.linear - rhs.linear, self.angular - rhs.angular)
    }
}

impl AddAssign for Motion {
    fn add_assign(&mut self, rhs: Motion) {
        self.linear += rhs.linear;
        self.angular += rhs.angular;
    }
}

impl Mul<Real> for Motion {
    type Output = Motion;
    fn mul(self, rhs: Real) -> Motion {
        Motion::new(self.linear * rhs, self.angular * rhs)
    }
}
