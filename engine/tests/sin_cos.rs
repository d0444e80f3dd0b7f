//! The engine's `sin_cos` (polynomial kernels after a three-part reduction by `π/2`)
//! against libm, which is correctly rounded in practice: within one unit in the last place
//! over the joint-angle range and beyond, exact at the quadrant boundaries' signs, libm's
//! own answer outside the reduced range, and the same bits one angle at a time as a slice
//! at once.

use ciflow_engine::math::{Real, sin_cos, sin_cos_slice};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Distance in units in the last place between two finite doubles of one sign.
fn ulps(a: Real, b: Real) -> u64 {
    if a == b {
        return 0;
    }
    assert_eq!(
        a.is_sign_negative(),
        b.is_sign_negative(),
        "{a} vs {b}: signs differ"
    );
    a.to_bits().abs_diff(b.to_bits())
}

#[test]
fn within_one_ulp_of_libm() {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let ranges = [1e-8, 0.7, 4.0, 40.0, 1e3, 1e4, 1e5];
    let (mut worst_sin, mut worst_cos) = (0, 0);
    for range in ranges {
        for _ in 0..200_000 {
            let x = rng.random_range(-range..=range);
            let (s, c) = sin_cos(x);
            let (s_ref, c_ref) = x.sin_cos();
            worst_sin = worst_sin.max(ulps(s, s_ref));
            worst_cos = worst_cos.max(ulps(c, c_ref));
        }
    }
    assert!(worst_sin <= 1, "sin: {worst_sin} ulp from libm");
    assert!(worst_cos <= 1, "cos: {worst_cos} ulp from libm");
}

#[test]
fn near_multiples_of_a_right_angle_the_result_keeps_its_relative_accuracy() {
    // Where sin or cos crosses zero the reduced angle is tiny: a reduction that lost the
    // low bits of π/2 would be wrong in most of the result's digits.
    for k in -2000i32..=2000 {
        let x = Real::from(k) * std::f64::consts::FRAC_PI_2;
        for x in [x.next_down(), x, x.next_up()] {
            let (s, c) = sin_cos(x);
            let (s_ref, c_ref) = x.sin_cos();
            assert!(ulps(s, s_ref) <= 1, "sin({x}) = {s}, libm {s_ref}");
            assert!(ulps(c, c_ref) <= 1, "cos({x}) = {c}, libm {c_ref}");
        }
    }
}

#[test]
fn signed_zero_large_and_non_finite_angles() {
    let (s, c) = sin_cos(-0.0);
    assert!(
        s == 0.0 && s.is_sign_negative() && c == 1.0,
        "sin_cos(-0) = ({s}, {c})"
    );
    for x in [2e5, -3.5e9, 1e300] {
        assert_eq!(
            sin_cos(x),
            x.sin_cos(),
            "libm's answer beyond the reduced range at {x}"
        );
    }
    for x in [Real::NAN, Real::INFINITY, Real::NEG_INFINITY] {
        let (s, c) = sin_cos(x);
        assert!(s.is_nan() && c.is_nan(), "sin_cos({x}) = ({s}, {c})");
    }
}

#[test]
fn a_slice_at_once_gives_the_bits_of_one_angle_at_a_time() {
    let mut rng = ChaCha8Rng::seed_from_u64(8);
    for len in 0..=11 {
        let mut x: Vec<Real> = (0..len).map(|_| rng.random_range(-7.0..=7.0)).collect();
        if len > 3 {
            x[2] = 4e7;
            x[3] = Real::NAN;
        }
        let (mut sin, mut cos) = (vec![0.0; len], vec![0.0; len]);
        sin_cos_slice(&x, &mut sin, &mut cos);
        for i in 0..len {
            let (s, c) = sin_cos(x[i]);
            assert_eq!(
                (sin[i].to_bits(), cos[i].to_bits()),
                (s.to_bits(), c.to_bits()),
                "angle {i} of {len}: {}",
                x[i]
            );
        }
    }
}
