//! Matrix exponential `e^{A t}` of a small square matrix (`n × n`), computed in a workspace
//! made once per size, so that a control loop can take one every period without touching
//! the heap.
//!
//! Scaling and squaring with the [13/13] Padé approximant (Higham 2005, "The scaling and
//! squaring method for the matrix exponential revisited", §2): with `B = A t / 2^s`, the
//! smallest `s ≥ 0` such that `‖B‖₁ ≤ θ₁₃ = 5.37`,
//!
//! `U = B [B⁶ (b₁₃ B⁶ + b₁₁ B⁴ + b₉ B²) + b₇ B⁶ + b₅ B⁴ + b₃ B² + b₁ I]`,
//! `V = B⁶ (b₁₂ B⁶ + b₁₀ B⁴ + b₈ B²) + b₆ B⁶ + b₄ B⁴ + b₂ B² + b₀ I`,
//!
//! `r₁₃(B) = (V − U)⁻¹ (V + U)` (LU with partial pivoting), and `e^{A t} = r₁₃(B)^{2^s}` by
//! `s` squarings. Six products and one solve; for `‖B‖₁ ≤ θ₁₃` the approximant's backward
//! error is below the unit roundoff of `f64`. (nalgebra's `exp` picks a lower-degree
//! approximant for small norms, at the cost of allocating its matrices on every call.)

use nalgebra::DMatrix;

/// `θ₁₃`: the largest `‖B‖₁` for which `r₁₃(B)` meets `f64`'s unit roundoff.
const THETA_13: f64 = 5.371_920_351_148_152;

/// The [13/13] Padé coefficients `b₀ … b₁₃`.
const PADE_13: [f64; 14] = [
    64_764_752_532_480_000.0,
    32_382_376_266_240_000.0,
    7_771_770_303_897_600.0,
    1_187_353_796_428_800.0,
    129_060_195_264_000.0,
    10_559_470_521_600.0,
    670_442_572_800.0,
    33_522_128_640.0,
    1_323_241_920.0,
    40_840_800.0,
    960_960.0,
    16_380.0,
    182.0,
    1.0,
];

/// The buffers of [`MatrixExp::exp_into`] for `n × n` matrices.
#[derive(Clone, Debug)]
pub struct MatrixExp {
    b: DMatrix<f64>,
    b2: DMatrix<f64>,
    b4: DMatrix<f64>,
    b6: DMatrix<f64>,
    u: DMatrix<f64>,
    v: DMatrix<f64>,
    sum: DMatrix<f64>,
}

impl MatrixExp {
    pub fn new(n: usize) -> Self {
        let zero = || DMatrix::zeros(n, n);
        Self {
            b: zero(),
            b2: zero(),
            b4: zero(),
            b6: zero(),
            u: zero(),
            v: zero(),
            sum: zero(),
        }
    }

    /// Size `n` of the matrices this workspace takes.
    pub fn dim(&self) -> usize {
        self.b.nrows()
    }

    /// `out = e^{a t}`. Panics unless `a` and `out` are `n × n` for this workspace's `n`, or
    /// if `a t` is not finite.
    pub fn exp_into(&mut self, a: &DMatrix<f64>, t: f64, out: &mut DMatrix<f64>) {
        let n = self.dim();
        assert!(
            a.shape() == (n, n) && out.shape() == (n, n),
            "matrices of {:?} and {:?} for a workspace of {n} × {n}",
            a.shape(),
            out.shape()
        );
        let norm = one_norm(a) * t.abs();
        assert!(norm.is_finite(), "e^(A t) of a matrix with ‖A t‖₁ = {norm}");
        let squarings = match norm > THETA_13 {
            true => (norm / THETA_13).log2().ceil() as i32,
            false => 0,
        };
        let Self {
            b,
            b2,
            b4,
            b6,
            u,
            v,
            sum,
        } = self;
        b.copy_from(a);
        *b *= t * 0.5f64.powi(squarings);
        b2.gemm(1.0, b, b, 0.0);
        b4.gemm(1.0, b2, b2, 0.0);
        b6.gemm(1.0, b4, b2, 0.0);
        let c = PADE_13;
        // U = B [B⁶ (b₁₃ B⁶ + b₁₁ B⁴ + b₉ B²) + b₇ B⁶ + b₅ B⁴ + b₃ B² + b₁ I]
        combine(sum, [(c[13], &*b6), (c[11], &*b4), (c[9], &*b2)], 0.0);
        combine(v, [(c[7], &*b6), (c[5], &*b4), (c[3], &*b2)], c[1]);
        v.gemm(1.0, b6, sum, 1.0);
        u.gemm(1.0, b, v, 0.0);
        // V = B⁶ (b₁₂ B⁶ + b₁₀ B⁴ + b₈ B²) + b₆ B⁶ + b₄ B⁴ + b₂ B² + b₀ I
        combine(sum, [(c[12], &*b6), (c[10], &*b4), (c[8], &*b2)], 0.0);
        combine(v, [(c[6], &*b6), (c[4], &*b4), (c[2], &*b2)], c[0]);
        v.gemm(1.0, b6, sum, 1.0);
        // (V − U) X = V + U: `sum` holds V − U and `out` the right-hand sides, then X.
        sum.copy_from(v);
        *sum -= &*u;
        out.copy_from(v);
        *out += &*u;
        solve_in_place(sum, out);
        for _ in 0..squarings {
            b.copy_from(out);
            out.gemm(1.0, b, b, 0.0);
        }
    }
}

/// `out = Σ cᵢ Mᵢ + diagonal I`.
fn combine(out: &mut DMatrix<f64>, terms: [(f64, &DMatrix<f64>); 3], diagonal: f64) {
    out.fill(0.0);
    for (c, m) in terms {
        for (o, m) in out.iter_mut().zip(m.iter()) {
            *o += c * m;
        }
    }
    for i in 0..out.nrows() {
        out[(i, i)] += diagonal;
    }
}

/// `‖A‖₁`, the largest column sum of absolute values.
fn one_norm(a: &DMatrix<f64>) -> f64 {
    a.column_iter()
        .map(|column| column.iter().map(|v| v.abs()).sum::<f64>())
        .fold(0.0, f64::max)
}

/// `rhs ← m⁻¹ rhs` by Gaussian elimination with partial pivoting, rows of `m` and `rhs`
/// swapped and overwritten as it goes. `V − U` of a Padé approximant within its `θ` is
/// well conditioned (Higham 2005, §2), so no pivot vanishes.
fn solve_in_place(m: &mut DMatrix<f64>, rhs: &mut DMatrix<f64>) {
    let n = m.nrows();
    for k in 0..n {
        let pivot = (k..n)
            .max_by(|&i, &j| m[(i, k)].abs().total_cmp(&m[(j, k)].abs()))
            .expect("k < n");
        if pivot != k {
            m.swap_rows(pivot, k);
            rhs.swap_rows(pivot, k);
        }
        let diagonal = m[(k, k)];
        for i in k + 1..n {
            let factor = m[(i, k)] / diagonal;
            if factor == 0.0 {
                continue;
            }
            for j in k..n {
                m[(i, j)] -= factor * m[(k, j)];
            }
            for j in 0..rhs.ncols() {
                rhs[(i, j)] -= factor * rhs[(k, j)];
            }
        }
    }
    for k in (0..n).rev() {
        for j in 0..rhs.ncols() {
            let known: f64 = (k + 1..n).map(|i| m[(k, i)] * rhs[(i, j)]).sum();
            rhs[(k, j)] = (rhs[(k, j)] - known) / m[(k, k)];
        }
    }
}
