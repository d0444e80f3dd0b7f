//! Spatial inertia of a rigid body.

use std::ops::{Add, AddAssign, Mul};

use super::{Force, Motion};
use crate::math::{Matrix3, Matrix6, Real, Vector3, skew};

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

    /// This inertia about a point `p` away, with the axes unchanged (the translation half
    /// of [`Se3::act_inertia`](super::Se3::act_inertia)): `h' = h + m p`,
    /// `I_o' = I_o − (p uᵀ + u pᵀ) + 2 (u · p) 1` with `u = h + ½ m p`.
    #[inline(always)]
    pub fn translated(&self, p: &Vector3) -> Inertia {
        let u = self.first_moment + p * (0.5 * self.mass);
        let pu = p * u.transpose();
        Inertia {
            mass: self.mass,
            first_moment: self.first_moment + p * self.mass,
            rotational: self.rotational - pu - pu.transpose()
                + Matrix3::from_diagonal_element(2.0 * u.dot(p)),
        }
    }

    /// This inertia turned by `θ` about the z axis, `(m, R h, R I_o Rᵀ)` with
    /// `R = Rz(θ)`, from `sin θ` and `cos θ`: `R` mixes only x and y, so the six distinct
    /// entries of `R I_o Rᵀ` take a dozen products instead of two 3×3 matrix products.
    #[inline(always)]
    pub fn rotated_about_z(&self, sin: Real, cos: Real) -> Inertia {
        let (h, i) = (&self.first_moment, &self.rotational);
        let (xx, yy, xy) = (i[(0, 0)], i[(1, 1)], i[(0, 1)]);
        let (xz, yz) = (i[(0, 2)], i[(1, 2)]);
        let (cc, ss, cs) = (cos * cos, sin * sin, cos * sin);
        let xx_new = cc * xx - 2.0 * cs * xy + ss * yy;
        let yy_new = ss * xx + 2.0 * cs * xy + cc * yy;
        let xy_new = cs * (xx - yy) + (cc - ss) * xy;
        let xz_new = cos * xz - sin * yz;
        let yz_new = sin * xz + cos * yz;
        Inertia {
            mass: self.mass,
            first_moment: Vector3::new(cos * h.x - sin * h.y, sin * h.x + cos * h.y, h.z),
            rotational: Matrix3::new(
                xx_new,
                xy_new,
                xz_new, //
                xy_new,
                yy_new,
                yz_new, //
                xz_new,
                yz_new,
                i[(2, 2)],
            ),
        }
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

    /// The rate of change `İ = (v ×*) I − I (v ×)` of this inertia, expressed in a fixed
    /// frame, while its body moves with `v`. It has the shape of an inertia of zero mass:
    ///
    /// ```text
    ///     ⎡ 0      −[c]× ⎤    c = m v + ω × h,
    /// İ = ⎣ [c]×    D    ⎦    D = A + Aᵀ − h vᵀ − v hᵀ + 2 (v · h) 1,  A = [ω]× I_o,
    /// ```
    ///
    /// from `[a]×[b]× − [b]×[a]× = [a × b]×` and `[a]×[b]× = b aᵀ − (a · b) 1`
    /// (Featherstone 2008, eq. 2.63, worked out block by block).
    pub fn variation(&self, v: &Motion) -> Inertia {
        let (omega, velocity) = (&v.angular, &v.linear);
        let h = &self.first_moment;
        let a = skew(omega) * self.rotational;
        let hv = h * velocity.transpose();
        Inertia {
            mass: 0.0,
            first_moment: velocity * self.mass + omega.cross(h),
            rotational: a + a.transpose() - hv - hv.transpose()
                + Matrix3::from_diagonal_element(2.0 * velocity.dot(h)),
        }
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

#[cfg(test)]
mod tests {
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    use super::*;
    use crate::spatial::Se3;

    fn vector(rng: &mut ChaCha8Rng) -> Vector3 {
        Vector3::from_fn(|_, _| rng.random_range(-1.0..=1.0))
    }

    fn motion(rng: &mut ChaCha8Rng) -> Motion {
        Motion::new(vector(rng), vector(rng))
    }

    /// A physically valid inertia: positive mass, offset centre of mass, `I_c = A Aᵀ`.
    fn inertia(rng: &mut ChaCha8Rng) -> Inertia {
        let a = Matrix3::from_fn(|_, _| rng.random_range(-1.0..=1.0));
        Inertia::from_com(rng.random_range(0.5..=3.0), vector(rng), a * a.transpose())
    }

    #[test]
    fn variation_matches_the_dense_product_formula() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        for _ in 0..100 {
            let (body, v) = (inertia(&mut rng), motion(&mut rng));
            let dense = body.to_matrix6();
            let expected = v.cross_force_matrix() * dense - dense * v.cross_matrix();
            let actual = body.variation(&v).to_matrix6();
            assert!(
                (actual - expected).amax() < 1e-12 * (1.0 + expected.amax()),
                "İ = (v×*) I − I (v×): {actual} vs {expected}"
            );
        }
    }

    /// The closed form for a turn about z against the dense `R I Rᵀ`.
    #[test]
    fn a_turn_about_z_is_the_dense_rotation() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        for _ in 0..100 {
            let body = inertia(&mut rng);
            let angle: Real = rng.random_range(-3.0..=3.0);
            let dense =
                Se3::from_rotation(Se3::rotation_about(&Vector3::z(), angle)).act_inertia(&body);
            let (sin, cos) = angle.sin_cos();
            let turned = body.rotated_about_z(sin, cos);
            assert_eq!(turned.mass, dense.mass);
            let error = (turned.first_moment - dense.first_moment)
                .amax()
                .max((turned.rotational - dense.rotational).amax());
            assert!(error < 1e-14, "off by {error}");
        }
    }

    #[test]
    fn transformed_inertia_maps_transformed_motion_to_transformed_momentum() {
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        for _ in 0..100 {
            let body = inertia(&mut rng);
            let angle = rng.random_range(-3.0..=3.0);
            let a_m_b = Se3::new(
                Se3::rotation_about(&vector(&mut rng).normalize(), angle),
                vector(&mut rng),
            );
            let m = motion(&mut rng);
            let expected = a_m_b.act_force(&(body * a_m_b.act_inv_motion(&m)));
            let actual = a_m_b.act_inertia(&body) * m;
            let error = (actual - expected).to_vector6().amax();
            assert!(error < 1e-12, "ᵃI m = X* (ᵇI (X⁻¹ m)): error {error}");
        }
    }
}
