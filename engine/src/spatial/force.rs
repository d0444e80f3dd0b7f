//! Spatial force vectors (wrenches).

use std::ops::{Add, AddAssign, Mul, Sub};

use crate::math::{Matrix6, Real, Vector3, Vector6, skew};

/// A spatial force `f = (f, n)`: the force and the moment about the frame origin, both in
/// the frame's axes.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Force {
    pub linear: Vector3,
    pub angular: Vector3,
}

impl Force {
    pub const fn new(linear: Vector3, angular: Vector3) -> Self {
        Self { linear, angular }
    }

    pub fn zero() -> Self {
        Self::default()
    }

    /// The matrix `(f ×̄*)` with `(f ×̄*) m = m ×* f`; it is skew-symmetric.
    pub fn cross_bar_matrix(&self) -> Matrix6 {
        let mut out = Matrix6::zeros();
        let f = -skew(&self.linear);
        out.fixed_view_mut::<3, 3>(0, 3).copy_from(&f);
        out.fixed_view_mut::<3, 3>(3, 0).copy_from(&f);
        out.fixed_view_mut::<3, 3>(3, 3)
            .copy_from(&-skew(&self.angular));
        out
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

impl Add for Force {
    type Output = Force;
    fn add(self, rhs: Force) -> Force {
        Force::new(self.linear + rhs.linear, self.angular + rhs.angular)
    }
}

impl Sub for Force {
    type Output = Force;
    fn sub(self, rhs: Force) -> Force {
        Force::new(self.linear - rhs.linear, self.angular - rhs.angular)
    }
}

impl AddAssign for Force {
    fn add_assign(&mut self, rhs: Force) {
        self.linear += rhs.linear;
        self.angular += rhs.angular;
    }
}

impl Mul<Real> for Force {
    type Output = Force;
    fn mul(self, rhs: Real) -> Force {
        Force::new(self.linear * rhs, self.angular * rhs)
    }
}
