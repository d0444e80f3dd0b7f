//! Rigid transforms and their action on spatial quantities.

use std::ops::Mul;

use super::{Force, Inertia, Motion};
use nalgebra::Rotation3;

use crate::math::{Isometry3, Matrix3, Real, UnitQuaternion, Vector3, sin_cos, skew};

/// A rigid transform `ᵃMᵦ = (R, p)` taking coordinates in frame `b` to frame `a`:
/// `xₐ = R x_b + p`. `act_*` maps a quantity from `b` to `a`, `act_inv_*` back.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Se3 {
    pub rotation: Matrix3,
    pub translation: Vector3,
}

impl Default for Se3 {
    fn default() -> Self {
        Self::identity()
    }
}

impl Se3 {
    pub const fn new(rotation: Matrix3, translation: Vector3) -> Self {
        Self {
            rotation,
            translation,
        }
    }

    pub fn identity() -> Self {
        Self::new(Matrix3::identity(), Vector3::zeros())
    }

    pub fn from_translation(translation: Vector3) -> Self {
        Self::new(Matrix3::identity(), translation)
    }

    pub fn from_rotation(rotation: Matrix3) -> Self {
        Self::new(rotation, Vector3::zeros())
    }

    /// Rotation by `angle` about the unit `axis` (Rodrigues:
    /// `R = 1 + sin θ [a]× + (1 − cos θ) [a]×²`).
    pub fn rotation_about(axis: &Vector3, angle: Real) -> Matrix3 {
        let (sin, cos) = sin_cos(angle);
        Self::rotation_about_from(axis, sin, cos)
    }

    /// [`rotation_about`](Self::rotation_about) from the angle's sine and cosine.
    pub fn rotation_about_from(axis: &Vector3, sin: Real, cos: Real) -> Matrix3 {
        let k = skew(axis);
        Matrix3::identity() + k * sin + k * k * (1.0 - cos)
    }

    pub fn inverse(&self) -> Se3 {
        let rt = self.rotation.transpose();
        Se3::new(rt, -(rt * self.translation))
    }

    pub fn act_point(&self, point: &Vector3) -> Vector3 {
        self.rotation * point + self.translation
    }

    /// `ᵃm = (R v + p × R ω, R ω)`.
    pub fn act_motion(&self, m: &Motion) -> Motion {
        let angular = self.rotation * m.angular;
        Motion::new(
            self.rotation * m.linear + self.translation.cross(&angular),
            angular,
        )
    }

    /// `ᵇm = (Rᵀ (v − p × ω), Rᵀ ω)`.
    pub fn act_inv_motion(&self, m: &Motion) -> Motion {
        Motion::new(
            self.rotation
                .tr_mul(&(m.linear - self.translation.cross(&m.angular))),
            self.rotation.tr_mul(&m.angular),
        )
    }

    /// `ᵃf = (R f, R n + p × R f)`.
    pub fn act_force(&self, f: &Force) -> Force {
        let linear = self.rotation * f.linear;
        Force::new(
            linear,
            self.rotation * f.angular + self.translation.cross(&linear),
        )
    }

    /// The z component of [`act_force`](Self::act_force)'s moment alone,
    /// `(R n + p × R f)_z = R₂ · n + p_x (R f)_y − p_y (R f)_x` with `R₂` the last row of
    /// `R`: 11 multiplications instead of the whole force's 24 (the CRBA's last crossing).
    pub fn act_force_moment_z(&self, f: &Force) -> Real {
        let r = &self.rotation;
        let (p, lin) = (&self.translation, &f.linear);
        let rotated_x = r[(0, 0)] * lin.x + r[(0, 1)] * lin.y + r[(0, 2)] * lin.z;
        let rotated_y = r[(1, 0)] * lin.x + r[(1, 1)] * lin.y + r[(1, 2)] * lin.z;
        let n = &f.angular;
        r[(2, 0)] * n.x + r[(2, 1)] * n.y + r[(2, 2)] * n.z + p.x * rotated_y - p.y * rotated_x
    }

    /// `ᵇf = (Rᵀ f, Rᵀ (n − p × f))`.
    pub fn act_inv_force(&self, f: &Force) -> Force {
        Force::new(
            self.rotation.tr_mul(&f.linear),
            self.rotation
                .tr_mul(&(f.angular - self.translation.cross(&f.linear))),
        )
    }

    /// The inertia `ᵃI = X* ᵇI X⁻¹` expressed about the origin of `a`:
    /// `m` unchanged, `h' = R h + m p`,
    /// `I_o' = R I_o Rᵀ − ([R h]×[p]× + [p]×[R h]× + m [p]×²)`, which with
    /// `[a]×[b]× = b aᵀ − (a · b) 1` and `u = R h + ½ m p` is
    /// `I_o' = R I_o Rᵀ − (p uᵀ + u pᵀ) + 2 (u · p) 1`.
    #[inline(always)]
    pub fn act_inertia(&self, inertia: &Inertia) -> Inertia {
        let rotated = Inertia {
            mass: inertia.mass,
            first_moment: self.rotation * inertia.first_moment,
            rotational: self.rotation * inertia.rotational * self.rotation.transpose(),
        };
        rotated.translated(&self.translation)
    }

    pub fn to_isometry(&self) -> Isometry3 {
        let rotation =
            UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(self.rotation));
        Isometry3::from_parts(self.translation.into(), rotation)
    }

    pub fn from_isometry(isometry: &Isometry3) -> Se3 {
        Se3::new(
            isometry.rotation.to_rotation_matrix().into_inner(),
            isometry.translation.vector,
        )
    }
}

/// Composition `ᵃMᵦ ᵇM_c = ᵃM_c`.
impl Mul for Se3 {
    type Output = Se3;
    fn mul(self, rhs: Se3) -> Se3 {
        Se3::new(
            self.rotation * rhs.rotation,
            self.rotation * rhs.translation + self.translation,
        )
    }
}

#[cfg(test)]
mod tests {
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    use super::*;

    fn vector(rng: &mut ChaCha8Rng) -> Vector3 {
        Vector3::from_fn(|_, _| rng.random_range(-1.0..=1.0))
    }

    /// The moment's z component alone against the whole force moved.
    #[test]
    fn a_moment_z_is_that_of_the_moved_force() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        for _ in 0..100 {
            let angle = rng.random_range(-3.0..=3.0);
            let axis = vector(&mut rng).normalize();
            let transform = Se3::new(Se3::rotation_about(&axis, angle), vector(&mut rng));
            let force = Force::new(vector(&mut rng), vector(&mut rng));
            let expected = transform.act_force(&force).angular.z;
            let actual = transform.act_force_moment_z(&force);
            assert!(
                (actual - expected).abs() < 1e-14 * (1.0 + expected.abs()),
                "{actual} vs {expected}"
            );
        }
    }
}
