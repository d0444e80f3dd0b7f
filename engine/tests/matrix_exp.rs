//! `MatrixExp` (`engine/src/math/matrix_exp.rs`) against nalgebra's `exp` and against
//! closed forms: random matrices from well inside the Padé approximant's range to many
//! squarings past it, the latent dynamics' stable rate matrices, rotations and diagonals.

use ciflow_engine::math::MatrixExp;
use nalgebra::DMatrix;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// `e^{a t}` through a fresh workspace.
fn exp(a: &DMatrix<f64>, t: f64) -> DMatrix<f64> {
    let n = a.nrows();
    let mut out = DMatrix::from_element(n, n, f64::NAN);
    MatrixExp::new(n).exp_into(a, t, &mut out);
    out
}

/// `‖a − b‖_max / max(1, ‖b‖_max)`.
fn relative_difference(a: &DMatrix<f64>, b: &DMatrix<f64>) -> f64 {
    (a - b).amax() / b.amax().max(1.0)
}

#[test]
fn random_matrices_match_nalgebra_from_small_norms_to_many_squarings() {
    let mut r = ChaCha8Rng::seed_from_u64(3);
    let mut worst = 0.0f64;
    for n in 1..=8 {
        for scale in [1e-6, 1e-2, 0.3, 1.0, 3.0, 10.0] {
            for t in [1.0, -0.5, 0.01] {
                let a = DMatrix::from_fn(n, n, |_, _| scale * r.random_range(-1.0..1.0));
                let expected = (&a * t).exp();
                let difference = relative_difference(&exp(&a, t), &expected);
                assert!(
                    difference < 1e-12,
                    "n = {n}, scale {scale}, t {t}: relative difference {difference:.2e}"
                );
                worst = worst.max(difference);
            }
        }
    }
    println!("worst relative difference to nalgebra: {worst:.2e}");
}

#[test]
fn a_stable_rate_matrix_decays_as_nalgebra_says_over_any_duration() {
    // The latent's `A = -(F Fᵀ + ε I) + (W - Wᵀ)`: every solution decays.
    let mut r = ChaCha8Rng::seed_from_u64(5);
    for n in [2, 3, 7] {
        let f = DMatrix::from_fn(n, n, |_, _| r.random_range(-2.0..2.0));
        let w = DMatrix::from_fn(n, n, |_, _| r.random_range(-2.0..2.0));
        let a = -(&f * f.transpose() + DMatrix::identity(n, n) * 0.5) + (&w - w.transpose());
        for t in [1e-4, 0.01, 0.37, 2.0, 30.0] {
            let ours = exp(&a, t);
            let difference = relative_difference(&ours, &(&a * t).exp());
            assert!(difference < 1e-12, "n = {n}, t {t}: {difference:.2e}");
            assert!(
                ours.norm() < n as f64,
                "n = {n}, t {t}: ‖e^(At)‖ = {}",
                ours.norm()
            );
        }
    }
}

#[test]
fn closed_forms_rotation_diagonal_zero_and_empty() {
    // A plane rotation by θ: [[0, −θ], [θ, 0]].
    for theta in [0.1f64, 1.0, 3.0, 40.0] {
        let a = DMatrix::from_row_slice(2, 2, &[0.0, -theta, theta, 0.0]);
        let (s, c) = theta.sin_cos();
        let rotation = DMatrix::from_row_slice(2, 2, &[c, -s, s, c]);
        let difference = relative_difference(&exp(&a, 1.0), &rotation);
        assert!(
            difference < 1e-13 * theta.max(1.0),
            "θ = {theta}: {difference:.2e}"
        );
    }
    let diagonal = DMatrix::from_diagonal(&nalgebra::DVector::from_vec(vec![-3.0, 0.5, 2.0]));
    let expected = DMatrix::from_diagonal(&nalgebra::DVector::from_vec(vec![
        (-6.0f64).exp(),
        1.0f64.exp(),
        4.0f64.exp(),
    ]));
    let difference = relative_difference(&exp(&diagonal, 2.0), &expected);
    assert!(difference < 1e-14, "diagonal: {difference:.2e}");
    assert_eq!(exp(&DMatrix::zeros(4, 4), 1.0), DMatrix::identity(4, 4));
    assert_eq!(exp(&DMatrix::zeros(0, 0), 1.0).shape(), (0, 0));
}

#[test]
fn a_workspace_of_another_size_is_refused() {
    let outcome = std::panic::catch_unwind(|| {
        let mut out = DMatrix::zeros(3, 3);
        MatrixExp::new(2).exp_into(&DMatrix::zeros(3, 3), 1.0, &mut out);
    });
    assert!(outcome.is_err());
}
