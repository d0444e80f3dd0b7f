//! Forward dynamics `q̈ = M(q)⁻¹ (τ − C(q, q̇) q̇ − g(q))` by CRBA, RNEA and an in-place
//! Cholesky factorisation `M = L Lᵀ`.
//!
//! Both run in world coordinates on one set of placed bodies (the CRBA's
//! [`bodies_in_world`]): the bias forces `C q̇ + g` by the RNEA in a fixed frame
//! (Featherstone 2008, §5.3: `vᵢ = vₚ + Sᵢ q̇ᵢ`, `aᵢ = aₚ + Ṡᵢ q̇ᵢ` with `Ṡᵢ = vᵢ × Sᵢ`,
//! `fᵢ = Iᵢ aᵢ + vᵢ ×* Iᵢ vᵢ`, `τᵢ = Sᵢᵀ Σ_{k ⪰ i} fₖ`, gravity as the base acceleration
//! `a₀ = −g`), where no quantity is carried from frame to frame, then the composites and
//! `M` from the same inertias.

use super::crba::{bodies_in_world, composite_rigid_body};
use super::kinematics::place_joints;
use super::{DynamicsError, check_vector};
use crate::math::simd::with_avx2_fma;
use crate::math::{DMatrix, DVector, Real, Vector3};
use crate::model::{Data, Model};
use crate::spatial::Motion;

/// `q̈` into `data.ddq`; `data.m` and `data.nle` hold `M(q)` and `C q̇ + g` afterwards.
pub fn forward_dynamics<'d>(
    model: &Model,
    data: &'d mut Data,
    q: &[Real],
    qd: &[Real],
    tau: &[Real],
) -> Result<&'d DVector, DynamicsError> {
    check_vector("q", q, model.nv())?;
    check_vector("qd", qd, model.nv())?;
    check_vector("tau", tau, model.nv())?;
    // The inner loop of every simulation: ~8 % faster with AVX2, and the same bits.
    with_avx2_fma(
        #[inline(always)]
        || solve(model, data, q, qd, tau),
    )?;
    Ok(&data.ddq)
}

/// [`forward_dynamics`] on checked inputs.
#[inline(always)]
fn solve(
    model: &Model,
    data: &mut Data,
    q: &[Real],
    qd: &[Real],
    tau: &[Real],
) -> Result<(), DynamicsError> {
    place_joints(model, data, q);
    bodies_in_world(model, data);
    bias_forces_in_world(model, data, qd);
    composite_rigid_body(model, data);
    data.cholesky.copy_from(&data.m);
    cholesky_in_place(&mut data.cholesky)?;
    for (i, ddq) in data.ddq.iter_mut().enumerate() {
        *ddq = tau[i] - data.nle[i];
    }
    cholesky_solve_in_place(&data.cholesky, &mut data.ddq);
    Ok(())
}

/// `C q̇ + g` into `data.nle` by the RNEA in world coordinates, on the bodies' own world
/// inertias and motion subspaces of [`bodies_in_world`].
#[inline(always)]
fn bias_forces_in_world(model: &Model, data: &mut Data, qd: &[Real]) {
    let n = model.nv();
    let (mut v, mut a) = (
        Motion::zero(),
        Motion::new(-model.gravity(), Vector3::zeros()),
    );
    let bodies = data.s_world.iter().zip(&data.ic_world).zip(qd);
    for (f, ((s, inertia), qd)) in data.f.iter_mut().zip(bodies) {
        let joint_velocity = *s * *qd;
        v += joint_velocity;
        a += v.cross(&joint_velocity);
        *f = *inertia * a + v.cross_force(&(*inertia * v));
    }
    for i in (0..n).rev() {
        data.nle[i] = data.f[i].dot(&data.s_world[i]);
        if i > 0 {
            let child = data.f[i];
            data.f[i - 1] += child;
        }
    }
}

/// Overwrites the lower triangle of the symmetric `matrix` with `L`, `matrix = L Lᵀ`,
/// except that the diagonal holds `1 / Lⱼⱼ`: divisions are the slow operations of a small
/// factorisation and its solve, so each pivot is inverted once and then multiplied by.
/// Column-major storage: `Lᵢⱼ` at `a[i + j n]`.
#[inline(always)]
fn cholesky_in_place(matrix: &mut DMatrix) -> Result<(), DynamicsError> {
    let n = matrix.nrows();
    let a = matrix.as_mut_slice();
    assert_eq!(a.len(), n * n);
    for j in 0..n {
        let mut diagonal = a[j + j * n];
        for k in 0..j {
            let l_jk = a[j + k * n];
            diagonal -= l_jk * l_jk;
        }
        // Also rejects a NaN pivot.
        if diagonal.is_nan() || diagonal <= 0.0 {
            return Err(DynamicsError::NotPositiveDefinite { joint: j });
        }
        let inverse = 1.0 / diagonal.sqrt();
        a[j + j * n] = inverse;
        for i in j + 1..n {
            let mut value = a[i + j * n];
            for k in 0..j {
                value -= a[i + k * n] * a[j + k * n];
            }
            a[i + j * n] = value * inverse;
        }
    }
    Ok(())
}

/// Solves `L Lᵀ x = b` in place (`b` becomes `x`), `factor` as
/// [`cholesky_in_place`] leaves it.
#[inline(always)]
fn cholesky_solve_in_place(factor: &DMatrix, b: &mut DVector) {
    let n = b.len();
    let l = factor.as_slice();
    let x = b.as_mut_slice();
    assert!(l.len() == n * n && x.len() == n);
    for i in 0..n {
        let mut value = x[i];
        for k in 0..i {
            value -= l[i + k * n] * x[k];
        }
        x[i] = value * l[i + i * n];
    }
    for i in (0..n).rev() {
        let mut value = x[i];
        for k in i + 1..n {
            value -= l[k + i * n] * x[k];
        }
        x[i] = value * l[i + i * n];
    }
}

#[cfg(test)]
mod tests {
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    use super::*;
    use crate::robot::panda;

    /// The AVX2 build [`forward_dynamics`] picks on this CPU and the baseline build
    /// (`solve` inlined into this test, compiled without AVX2) agree to the bit: wider
    /// registers, same operations. Code that picks its arithmetic by instruction set (as
    /// the MLP's `tanh` fuses its multiply-adds under FMA) would break it.
    #[test]
    fn the_avx2_build_returns_the_bits_of_the_baseline_build() {
        let robot = panda();
        let model = robot.model();
        let (mut dispatched, mut baseline) = (Data::new(model), Data::new(model));
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        for _ in 0..200 {
            let mut draw = |scale: f64| -> Vec<Real> {
                (0..model.nv())
                    .map(|_| scale * rng.random_range(-1.0..1.0))
                    .collect()
            };
            let (q, qd, tau) = (draw(2.5), draw(3.0), draw(40.0));
            let fast = forward_dynamics(model, &mut dispatched, &q, &qd, &tau).unwrap();
            solve(model, &mut baseline, &q, &qd, &tau).unwrap();
            let bits = |v: &DVector| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(fast), bits(&baseline.ddq));
        }
    }
}
