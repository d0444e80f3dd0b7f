//! Spatial inertia of a rigid body.

use std::ops::{Add, AddAssign, Mul};

use super::{Force, Motion, skew};
use crate::math::{Matrix3, Matrix6, Real, Vector3};

/// A spatial inertia about the frame origin, stored as the mass `m`, the first moment of
/// mass `h = m c` (`c` the centre of mass) and the rotational inertia about the origin
/// `I_o = I_c + m [c]×ᵀ[c]×`. As a matrix (`[linear; angular]` ordering)
///
/// ```text
///     ⎡ m 1     −[h]× ⎤
/// I = ⎣ [h]×     I_o  ⎦
/// ```
///
/// Inertias of bodies rigidly attached to one frame add component-wise.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Inertia {
    pub mass: Real,
    pub first_moment: Vector3,
    pub rotational: Matrix3,
}

impl Inertia {
    pub fn zero() -> Self {
        Self::default()
    }

    /// From the mass, the centre of mass `c` and the rotational inertia `I_c` about the
    /// centre of mass (parallel-axis theorem: `I_o = I_c + m ([c]×)ᵀ [c]×`).
    pub fn from_com(mass: Real, com: Vector3, inertia_com: Matrix3) -> Self {
        let c = skew(&com);
        Self {
            mass,
            first_moment: com * mass,
            rotational: inertia_com + c.transpose() * c * mass,
        }
    }

    /// The centre of mass `c = h / m` (the origin for a massless body).
    pub fn com(&self) -> Vector3 {
        if self.mass > 0.0 {
            self.first_moment / self.mass
        } else {
            Vector3::zeros()
        }
    }

    /// The rotational inertia about the centre of mass, `I_c = I_o − m [c]×ᵀ[c]×`.
    pub fn inertia_com(&self) -> Matrix3 {
        let c = skew(&self.com());
        self.rotational - c.transpose() * c * self.mass
    }

    /// The 6×6 matrix form (see the type docs).
    pub fn to_matrix6(&self) -> Matrix6 {
        let mut out = Matrix6::zeros();
        let h = skew(&self.first_moment);
        out.fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&(Matrix3::identity() * self.mass));
        out.fixed_view_mut::<3, 3>(0, 3).copy_from(&-h);
        out.fixed_view_mut::<3, 3>(3, 0).copy_from(&h);
        out.fixed_view_mut::<3, 3>(3, 3).copy_from(&self.rotational);
        out
    }

    /// Kinetic energy `½ vᵀ I v` of the body moving with `v`.
    pub fn kinetic_energy(&self, v: &Motion) -> Real {
        0.5 * (*self * *v).dot(v)
    }
}

/// The momentum `I v = (m v − h × ω, h × v + I_o ω)`.
impl Mul<Motion> for Inertia {
    type Output = Force;
    fn mul(self, v: Motion) -> Force {
        Force {
            linear: v.linear * self.mass - self.first_moment.cross(&v.angular),
            angular: self.first_moment.cross(&v.linear) + self.rotational * v.angular,
        }
    }
}

impl Add for Inertia {
    type Output = Inertia;
    fn add(mut self, rhs: Inertia) -> Inertia {
        self += rhs;
        self
    }
}

impl AddAssign for Inertia {
    fn add_assign(&mut self, rhs: Inertia) {
        self.mass += rhs.mass;
        self.first_moment += rhs.first_moment;
        self.rotational += rhs.rotational;
    }
}
