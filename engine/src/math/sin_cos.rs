//! `sin x` and `cos x` together, for one angle or for every joint of a robot at once.
//!
//! Every dynamics algorithm starts by placing each joint, which takes the sine and cosine
//! of each joint angle; through libm's scalar `sincos` that was about a fifth of the
//! CRBA's time on the Panda. Here the angle is reduced to `r = x − k π/2`,
//! `|r| ≤ π/4` (Cody–Waite: `π/2` split into three parts so that `k P₁` and `k P₂` are
//! exact), the sine and cosine of `r` are minimax polynomials (the coefficients of
//! fdlibm's `__kernel_sin` / `__kernel_cos`, error below one unit in the last place), and
//! the quadrant `k mod 4` permutes and signs them. Nothing branches on the value, so the
//! compiler runs several angles per SIMD instruction in [`sin_cos_slice`].
//!
//! The result is within one unit in the last place of the correctly rounded value
//! (`tests/sin_cos.rs` compares it with libm). Angles beyond [`REDUCED_RANGE`] (where
//! `k P₂` would no longer be exact) and non-finite ones go to libm.

/// `|x|` up to which the reduction keeps its accuracy: `k < 2¹⁶`, so `k P₁` and `k P₂`
/// are exact.
pub const REDUCED_RANGE: f64 = 1.0e5;

/// `π/2` in three parts: `P₁`, `P₂` with 33 significant bits each, `P₃` the rest.
const PI_2_PART1: f64 = 1.570_796_326_734_125_6;
const PI_2_PART2: f64 = 6.077_100_506_303_966e-11;
const PI_2_PART3: f64 = 2.022_266_248_795_950_6e-21;
const TWO_OVER_PI: f64 = std::f64::consts::FRAC_2_PI;
/// `1.5 · 2⁵²`: adding it rounds to an integer, which then sits in the low mantissa bits.
const ROUND_SHIFT: f64 = 6_755_399_441_055_744.0;

const SIN: [f64; 6] = [
    -1.666_666_666_666_663_2e-1,
    8.333_333_333_322_49e-3,
    -1.984_126_982_985_795e-4,
    2.755_731_370_707_006_8e-6,
    -2.505_076_025_340_686_3e-8,
    1.589_690_995_211_55e-10,
];
const COS: [f64; 6] = [
    4.166_666_666_666_66e-2,
    -1.388_888_888_887_411e-3,
    2.480_158_728_947_673e-5,
    -2.755_731_435_139_066_3e-7,
    2.087_572_321_298_175e-9,
    -1.135_964_755_778_819_5e-11,
];

/// `(sin x, cos x)`.
#[inline]
pub fn sin_cos(x: f64) -> (f64, f64) {
    if in_reduced_range(x) {
        reduced_sin_cos(x)
    } else {
        x.sin_cos()
    }
}

/// `sin[i], cos[i] = sin x[i], cos x[i]` for every `i` (all three of one length).
///
/// # Panics
/// If the lengths differ.
#[inline(always)]
pub fn sin_cos_slice(x: &[f64], sin: &mut [f64], cos: &mut [f64]) {
    assert!(
        x.len() == sin.len() && x.len() == cos.len(),
        "sin_cos_slice: {} angles, {} sines, {} cosines",
        x.len(),
        sin.len(),
        cos.len()
    );
    const LANES: usize = 4;
    let (x_chunks, x_rest) = x.as_chunks::<LANES>();
    let (sin_chunks, sin_rest) = sin.as_chunks_mut::<LANES>();
    let (cos_chunks, cos_rest) = cos.as_chunks_mut::<LANES>();
    for ((x, sin), cos) in x_chunks.iter().zip(sin_chunks).zip(cos_chunks) {
        (*sin, *cos) = reduced_sin_cos_lanes(x);
    }
    let mut padded = [0.0; LANES];
    padded[..x_rest.len()].copy_from_slice(x_rest);
    let (s, c) = reduced_sin_cos_lanes(&padded);
    sin_rest.copy_from_slice(&s[..x_rest.len()]);
    cos_rest.copy_from_slice(&c[..x_rest.len()]);
    // The rare angle outside the reduced range, after the fact so the lanes stay branch-free.
    for (i, &x) in x.iter().enumerate() {
        if !in_reduced_range(x) {
            (sin[i], cos[i]) = x.sin_cos();
        }
    }
}

/// False for NaN as well.
#[inline(always)]
fn in_reduced_range(x: f64) -> bool {
    x.abs() <= REDUCED_RANGE
}

#[inline(always)]
fn reduced_sin_cos_lanes<const N: usize>(x: &[f64; N]) -> ([f64; N], [f64; N]) {
    let (mut sin, mut cos) = ([0.0; N], [0.0; N]);
    for i in 0..N {
        (sin[i], cos[i]) = reduced_sin_cos(x[i]);
    }
    (sin, cos)
}

/// `(sin x, cos x)` for `|x| ≤ REDUCED_RANGE`, without a branch.
#[inline(always)]
fn reduced_sin_cos(x: f64) -> (f64, f64) {
    let shifted = x * TWO_OVER_PI + ROUND_SHIFT;
    let quadrant = shifted.to_bits();
    let k = shifted - ROUND_SHIFT;
    // `x − k P₁` and `k P₂` are exact; `r + tail` is the reduced angle to about twice
    // the precision of `r`, and the kernels use the tail (dropping it cost up to 2 ulp).
    let high = x - k * PI_2_PART1;
    let low = k * PI_2_PART2;
    let r = high - low;
    let tail = ((high - r) - low) - k * PI_2_PART3;
    let (s, c) = (kernel_sin(r, tail), kernel_cos(r, tail));
    // Quadrant 1: (cos r, −sin r); 2: (−sin r, −cos r); 3: (−cos r, sin r).
    let (s, c) = if quadrant & 1 == 1 { (c, s) } else { (s, c) };
    let sin_sign = (quadrant & 2) << 62;
    let cos_sign = (quadrant.wrapping_add(1) & 2) << 62;
    (
        f64::from_bits(s.to_bits() ^ sin_sign),
        f64::from_bits(c.to_bits() ^ cos_sign),
    )
}

/// `sin(r + t)` for `|r| ≤ π/4` and `|t|` below an ulp of `r`:
/// `r + r³ (S₁ + r² (S₂ + … + r⁸ S₆)) + t (1 − r²/2)`.
#[inline(always)]
fn kernel_sin(r: f64, t: f64) -> f64 {
    let z = r * r;
    let w = z * z;
    let poly = SIN[1] + z * (SIN[2] + z * SIN[3]) + z * w * (SIN[4] + z * SIN[5]);
    let sin = r + (z * r * (SIN[0] + z * poly) + t * (1.0 - 0.5 * z));
    // `−0 + 0` would lose the sign of `sin(−0) = −0`.
    if r == 0.0 { r } else { sin }
}

/// `cos(r + t)` for `|r| ≤ π/4` and `|t|` below an ulp of `r`:
/// `1 − r²/2 + r⁴ (C₁ + … + r¹⁰ C₆) − r t`, with `1 − r²/2` rounded once and its rounding
/// error added back (what keeps the error under one ulp).
#[inline(always)]
fn kernel_cos(r: f64, t: f64) -> f64 {
    let z = r * r;
    let w = z * z;
    let poly =
        z * (COS[0] + z * (COS[1] + z * COS[2])) + w * w * (COS[3] + z * (COS[4] + z * COS[5]));
    let half_z = 0.5 * z;
    let head = 1.0 - half_z;
    head + (((1.0 - head) - half_z) + (z * poly - r * t))
}
