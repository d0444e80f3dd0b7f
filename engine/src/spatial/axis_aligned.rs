//! Rotations that map every coordinate axis onto a coordinate axis: signed permutation
//! matrices, the joint placements of Denavit–Hartenberg-style chains (URDF `rpy` angles
//! that are multiples of `π/2`, as in the Panda and the UR5e). Applying one moves and
//! negates entries instead of multiplying by a dense 3×3 matrix.

use super::Inertia;
use crate::math::{Matrix3, Real, Vector3};

/// Entries within this of 0 or ±1 count as exactly 0 or ±1: `cos(π/2)` in `f64` is
/// `6.1e-17`, and a URDF's `rpy` goes through a few more roundings than that.
const TOLERANCE: Real = 1e-14;

/// A signed permutation matrix `R`: row `r` holds `sign[r]` in column `source[r]` and
/// zeros elsewhere, so `(R v)ᵣ = sign[r] v[source[r]]`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AxisAlignedRotation {
    source: [usize; 3],
    sign: [Real; 3],
}

impl AxisAlignedRotation {
    /// `rotation` as a signed permutation, if it is one (entries within `1e-14` of 0 or
    /// ±1, treated as exact; one non-zero per row and per column, determinant +1).
    pub fn from_matrix(rotation: &Matrix3) -> Option<Self> {
        let mut source = [0; 3];
        let mut sign = [0.0; 3];
        for r in 0..3 {
            let mut nonzero = None;
            for c in 0..3 {
                let entry = rotation[(r, c)];
                if (entry.abs() - 1.0).abs() <= TOLERANCE {
                    if nonzero.is_some() {
                        return None;
                    }
                    nonzero = Some((c, entry.signum()));
                } else if entry.abs() > TOLERANCE {
                    return None;
                }
            }
            (source[r], sign[r]) = nonzero?;
        }
        let permutation = source.contains(&0) && source.contains(&1) && source.contains(&2);
        let rotation = Self { source, sign };
        (permutation && rotation.to_matrix().determinant() > 0.0).then_some(rotation)
    }

    /// The matrix `R` (exact zeros and ones).
    pub fn to_matrix(&self) -> Matrix3 {
        Matrix3::from_fn(|r, c| {
            if self.source[r] == c {
                self.sign[r]
            } else {
                0.0
            }
        })
    }

    /// `R v`.
    #[inline(always)]
    pub fn rotate(&self, v: &Vector3) -> Vector3 {
        Vector3::from_fn(|r, _| self.sign[r] * v[self.source[r]])
    }

    /// The inertia expressed in axes turned by `R` (same origin): `(m, R h, R I_o Rᵀ)`,
    /// where `(R I_o Rᵀ)ᵣₜ = sign[r] sign[t] (I_o)_{source[r] source[t]}`.
    #[inline(always)]
    pub fn rotate_inertia(&self, inertia: &Inertia) -> Inertia {
        let i = &inertia.rotational;
        Inertia {
            mass: inertia.mass,
            first_moment: self.rotate(&inertia.first_moment),
            rotational: Matrix3::from_fn(|r, t| {
                self.sign[r] * self.sign[t] * i[(self.source[r], self.source[t])]
            }),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::spatial::Se3;

    fn rpy(roll: Real, pitch: Real, yaw: Real) -> Matrix3 {
        Se3::rotation_about(&Vector3::z(), yaw)
            * Se3::rotation_about(&Vector3::y(), pitch)
            * Se3::rotation_about(&Vector3::x(), roll)
    }

    #[test]
    fn quarter_turns_are_recognised_and_other_rotations_are_not() {
        use std::f64::consts::FRAC_PI_2;
        for (roll, pitch, yaw) in [
            (0.0, 0.0, 0.0),
            (FRAC_PI_2, 0.0, 0.0),
            (-FRAC_PI_2, 0.0, 0.0),
            (FRAC_PI_2, FRAC_PI_2, 0.0),
            (0.0, -FRAC_PI_2, 2.0 * FRAC_PI_2),
        ] {
            let matrix = rpy(roll, pitch, yaw);
            let rotation = AxisAlignedRotation::from_matrix(&matrix)
                .unwrap_or_else(|| panic!("rpy ({roll}, {pitch}, {yaw}) not recognised"));
            assert!((rotation.to_matrix() - matrix).amax() < 1e-15);
        }
        for (roll, pitch, yaw) in [(0.3, 0.0, 0.0), (FRAC_PI_2, 0.0, 1e-9), (0.0, 1.0, 2.0)] {
            assert_eq!(
                AxisAlignedRotation::from_matrix(&rpy(roll, pitch, yaw)),
                None
            );
        }
        // A reflection is a signed permutation but not a rotation.
        let mirror = Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, -1.0));
        assert_eq!(AxisAlignedRotation::from_matrix(&mirror), None);
    }

    #[test]
    fn moving_entries_is_the_matrix_product() {
        let matrix = rpy(
            std::f64::consts::FRAC_PI_2,
            0.0,
            -std::f64::consts::FRAC_PI_2,
        );
        let rotation = AxisAlignedRotation::from_matrix(&matrix).unwrap();
        let exact = rotation.to_matrix();
        let v = Vector3::new(0.3, -1.7, 2.9);
        assert_eq!(rotation.rotate(&v), exact * v);
        let a = Matrix3::new(0.9, 0.1, -0.3, 0.4, 1.2, 0.2, -0.5, 0.6, 0.8);
        let inertia = Inertia::from_com(2.5, Vector3::new(0.1, -0.2, 0.05), a * a.transpose());
        let moved = rotation.rotate_inertia(&inertia);
        let expected = Se3::from_rotation(exact).act_inertia(&inertia);
        assert_eq!(moved.mass, expected.mass);
        assert!((moved.first_moment - expected.first_moment).amax() < 1e-16);
        assert!((moved.rotational - expected.rotational).amax() < 1e-15);
    }
}
