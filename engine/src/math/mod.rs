//! Scalar and linear-algebra aliases used across the engine.

/// The scalar of all dynamics computations.
pub type Real = f64;
/// A dynamically sized column vector (joint positions, velocities, torques).
pub type DVector = nalgebra::DVector<Real>;
/// A dynamically sized matrix (mass matrix, Jacobians).
pub type DMatrix = nalgebra::DMatrix<Real>;
pub type Vector3 = nalgebra::Vector3<Real>;
pub type Vector6 = nalgebra::Vector6<Real>;
pub type Matrix3 = nalgebra::Matrix3<Real>;
pub type Matrix6 = nalgebra::Matrix6<Real>;
pub type Isometry3 = nalgebra::Isometry3<Real>;
pub type UnitQuaternion = nalgebra::UnitQuaternion<Real>;

/// Euclidean distance `‖a − b‖` between two points given as equally long slices.
pub fn distance(a: &[Real], b: &[Real]) -> Real {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y) * (x - y))
        .sum::<Real>()
        .sqrt()
}

/// The cross-product matrix `[x]×` with `[x]× y = x × y`.
pub fn skew(x: &Vector3) -> Matrix3 {
    Matrix3::new(0.0, -x.z, x.y, x.z, 0.0, -x.x, -x.y, x.x, 0.0)
}

mod matrix_exp;
pub(crate) mod simd;
mod sin_cos;
pub use matrix_exp::MatrixExp;
pub use sin_cos::{sin_cos, sin_cos_slice};
