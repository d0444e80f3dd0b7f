//! Multilayer perceptron `h_{j+1} = tanh(W_j h_j + b_j)`, linear last layer.
//!
//! `tanh` keeps the network smooth (the acceleration feed-forward differentiates it twice)
//! and its Jacobian bounded. Weights are stored transposed (`[in][out]`) so each input
//! adds a contiguous row to the output, a loop the compiler vectorises; dual-number
//! activations are split into their `f64` components ([`Scalar::LANES`]) so `W`
//! multiplies the values and all their derivative parts in one sweep over the weights.

use std::marker::PhantomData;

use super::error::FlowResult;
use super::scalar::Scalar;
use super::weights::Weights;

/// Names and shapes `{prefix}.{j}.weight: [out, in]`, `{prefix}.{j}.bias: [out]`, as
/// `tch::nn::linear` creates them.
pub fn mlp_parameter_shapes(prefix: &str, sizes: &[usize]) -> Vec<(String, Vec<usize>)> {
    sizes
        .windows(2)
        .enumerate()
        .flat_map(|(j, io)| {
            [
                (format!("{prefix}.{j}.weight"), vec![io[1], io[0]]),
                (format!("{prefix}.{j}.bias"), vec![io[1]]),
            ]
        })
        .collect()
}

#[derive(Clone, Debug)]
struct Linear {
    inputs: usize,
    /// Outputs rounded up to a multiple of [`NARROW`]; the padding has zero weights.
    padded_outputs: usize,
    /// Outputs covered by the wide panels, a multiple of [`WIDE`].
    wide_outputs: usize,
    /// `W` in panels: the panel of outputs `o..o + width` holds `[inputs][width]` at
    /// `o * inputs`, the weights input after input, so a block of outputs streams through
    /// contiguous memory. [`WIDE`] panels first, then [`NARROW`] ones for the rest.
    panels: Vec<f64>,
    /// `b`, zero-padded to `padded_outputs`.
    bias: Vec<f64>,
}

/// Outputs per wide weight panel (eight 4-wide vectors).
const WIDE: usize = 32;
/// Outputs per narrow weight panel (two 4-wide vectors), and the padding unit.
const NARROW: usize = 8;

impl Linear {
    fn new(weight: &[f64], bias: &[f64], inputs: usize, outputs: usize) -> Self {
        let padded_outputs = outputs.div_ceil(NARROW) * NARROW;
        let wide_outputs = padded_outputs - padded_outputs % WIDE;
        let mut linear = Self {
            inputs,
            padded_outputs,
            wide_outputs,
            panels: vec![0.0; inputs * padded_outputs],
            bias: vec![0.0; padded_outputs],
        };
        linear.bias[..outputs].copy_from_slice(bias);
        for (o, row) in weight.chunks_exact(inputs).enumerate() {
            let (first, width) = linear.panel_of(o);
            for (i, w) in row.iter().enumerate() {
                linear.panels[first * inputs + i * width + o - first] = *w;
            }
        }
        linear
    }

    /// First output and width of the panel holding output `o`.
    fn panel_of(&self, o: usize) -> (usize, usize) {
        if o < self.wide_outputs {
            (o - o % WIDE, WIDE)
        } else {
            (o - (o - self.wide_outputs) % NARROW, NARROW)
        }
    }

    /// The panels as `(first output, width, weights)`.
    fn panels<'a>(&'a self) -> impl Iterator<Item = (usize, usize, &'a [f64])> {
        let (wide, narrow) = self.panels.split_at(self.wide_outputs * self.inputs);
        let inputs = self.inputs;
        let panels = move |weights: &'a [f64], width: usize, offset: usize| {
            weights
                .chunks_exact(width * inputs)
                .enumerate()
                .map(move |(q, w)| (offset + q * width, width, w))
        };
        panels(wide, WIDE, 0).chain(panels(narrow, NARROW, self.wide_outputs))
    }

    /// `out_l = W x_l + [l = 0 and with_bias] b` for the `lanes` components of the
    /// activations, stored interleaved (`x[i * lanes + l]`, the memory layout of a `[S]`)
    /// over the first `inputs` entries of `x` and `padded_outputs` entries of `out`.
    ///
    /// The bias is a constant, so it enters the primal component only.
    fn apply(&self, x: &[f64], lanes: usize, with_bias: bool, out: &mut [f64], simd: Simd) {
        let (x, out) = (
            &x[..self.inputs * lanes],
            &mut out[..self.padded_outputs * lanes],
        );
        match simd {
            #[cfg(target_arch = "x86_64")]
            Simd::Avx2Fma => {
                // SAFETY: `Simd::Avx2Fma` is only chosen once both features were detected.
                unsafe { avx2::apply(self, x, lanes, with_bias, out) }
            }
            Simd::Portable => self.apply_portable(x, lanes, with_bias, out),
        }
    }

    fn apply_portable(&self, x: &[f64], lanes: usize, with_bias: bool, out: &mut [f64]) {
        for (o, outputs) in out.chunks_exact_mut(lanes).enumerate() {
            outputs.fill(0.0);
            if with_bias {
                outputs[0] = self.bias[o];
            }
        }
        for (first, width, panel) in self.panels() {
            let out = &mut out[first * lanes..(first + width) * lanes];
            for (w, x) in panel.chunks_exact(width).zip(x.chunks_exact(lanes)) {
                for (w, outputs) in w.iter().zip(out.chunks_exact_mut(lanes)) {
                    for (o, x) in outputs.iter_mut().zip(x) {
                        *o += x * w;
                    }
                }
            }
        }
    }
}

/// Which instruction set [`Mlp::eval`] runs on.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Simd {
    Portable,
    #[cfg(target_arch = "x86_64")]
    Avx2Fma,
}

impl Simd {
    fn detect() -> Self {
        if std::env::var_os("B3_PORTABLE").is_some() { return Self::Portable; }
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
        {
            return Self::Avx2Fma;
        }
        Self::Portable
    }
}

/// The AVX2 + FMA kernel of [`Linear::apply`].
///
/// Blocks of outputs accumulate in registers while the inputs stream by, about eight
/// 4-wide accumulators at a time so the fused multiply-add latency stays hidden: for `L`
/// lanes at a time, blocks of `32 / L` outputs of the wide panels, then the narrow panels
/// with their inputs split into `4 / L` interleaved partial sums. The weights of a block
/// are loaded once for all lanes.
#[cfg(target_arch = "x86_64")]
mod avx2 {
    use std::arch::x86_64::*;

    use super::{Linear, NARROW, WIDE};

    /// # Safety
    /// The CPU supports AVX2 and FMA; `x` holds `linear.inputs * lanes` values and `out`
    /// `linear.padded_outputs * lanes`.
    #[target_feature(enable = "avx2,fma")]
    pub(super) unsafe fn apply(
        linear: &Linear,
        x: &[f64],
        lanes: usize,
        with_bias: bool,
        out: &mut [f64],
    ) {
        assert!(x.len() == linear.inputs * lanes && out.len() == linear.padded_outputs * lanes);
        // SAFETY (all blocks): the assertion above and the panel layout of `Linear::new`
        // keep every access in bounds.
        unsafe {
            match lanes {
                1 => lane_group::<1, 8, 4>(linear, x, 1, 0, with_bias, out),
                2 => lane_group::<2, 4, 2>(linear, x, 2, 0, with_bias, out),
                _ => {
                    for first in (0..lanes).step_by(4) {
                        lane_group::<4, 2, 1>(linear, x, lanes, first, with_bias, out);
                    }
                }
            }
        }
    }

    /// Lanes `first..first + L`: blocks of `4 V` outputs of the wide panels, then the
    /// narrow panels with `SPLIT` partial sums.
    #[target_feature(enable = "avx2,fma")]
    unsafe fn lane_group<const L: usize, const V: usize, const SPLIT: usize>(
        linear: &Linear,
        x: &[f64],
        lanes: usize,
        first: usize,
        with_bias: bool,
        out: &mut [f64],
    ) {
        let bias = (with_bias && first == 0).then_some(linear.bias.as_ptr());
        let inputs = linear.inputs;
        let x = unsafe { x.as_ptr().add(first) };
        let out = unsafe { out.as_mut_ptr().add(first) };
        let panels = linear.panels.as_ptr();
        for start in (0..linear.wide_outputs).step_by(4 * V) {
            let panel_start = start - start % WIDE;
            let weights = unsafe { panels.add(panel_start * inputs + start - panel_start) };
            let block = Block::<WIDE> { weights, inputs, x, lanes };
            unsafe { block.run::<L, V, 1>(bias.map(|b| b.add(start)), out.add(start * lanes)) };
        }
        for start in (linear.wide_outputs..linear.padded_outputs).step_by(NARROW) {
            let weights = unsafe { panels.add(start * inputs) };
            let block = Block::<NARROW> { weights, inputs, x, lanes };
            unsafe {
                block.run::<L, { NARROW / 4 }, SPLIT>(
                    bias.map(|b| b.add(start)),
                    out.add(start * lanes),
                )
            };
        }
    }

    /// A block of outputs: `weights` points at its first column in a panel of width `W`,
    /// `x` at the first lane of input 0.
    struct Block<const W: usize> {
        weights: *const f64,
        inputs: usize,
        x: *const f64,
        lanes: usize,
    }

    impl<const W: usize> Block<W> {
        /// `out[o * lanes + l] = Σ_i w[i][o] x[i * lanes + l] (+ bias[o] for l = 0)` for
        /// `o < 4 V`, `l < L`, the inputs summed in `P` interleaved partial sums.
        #[target_feature(enable = "avx2,fma")]
        unsafe fn run<const L: usize, const V: usize, const P: usize>(
            &self,
            bias: Option<*const f64>,
            out: *mut f64,
        ) {
            let mut acc = [[[_mm256_setzero_pd(); V]; L]; P];
            if let Some(bias) = bias {
                for (v, a) in acc[0][0].iter_mut().enumerate() {
                    *a = unsafe { _mm256_loadu_pd(bias.add(4 * v)) };
                }
            }
            let full = self.inputs - self.inputs % P;
            for i in (0..full).step_by(P) {
                for (p, partial) in acc.iter_mut().enumerate() {
                    unsafe { self.accumulate(i + p, partial) };
                }
            }
            for i in full..self.inputs {
                unsafe { self.accumulate(i, &mut acc[0]) };
            }
            let (total, partials) = acc.split_first_mut().expect("P >= 1");
            for partial in partials.iter() {
                for (t, p) in total.as_flattened_mut().iter_mut().zip(partial.as_flattened()) {
                    *t = _mm256_add_pd(*t, *p);
                }
            }
            if L == 1 && self.lanes == 1 {
                for (v, t) in total[0].iter().enumerate() {
                    unsafe { _mm256_storeu_pd(out.add(4 * v), *t) };
                }
                return;
            }
            for (l, lane) in total.iter().enumerate() {
                for (v, t) in lane.iter().enumerate() {
                    let mut values = [0.0; 4];
                    unsafe { _mm256_storeu_pd(values.as_mut_ptr(), *t) };
                    for (k, value) in values.into_iter().enumerate() {
                        unsafe { *out.add((4 * v + k) * self.lanes + l) = value };
                    }
                }
            }
        }

        /// `acc_l += w[input] x_l[input]`.
        #[target_feature(enable = "avx2,fma")]
        #[inline]
        unsafe fn accumulate<const L: usize, const V: usize>(
            &self,
            input: usize,
            acc: &mut [[__m256d; V]; L],
        ) {
            let row = unsafe { self.weights.add(input * W) };
            let w: [__m256d; V] =
                std::array::from_fn(|v| unsafe { _mm256_loadu_pd(row.add(4 * v)) });
            let x = unsafe { self.x.add(input * self.lanes) };
            for (l, acc) in acc.iter_mut().enumerate() {
                let x = unsafe { _mm256_broadcast_sd(&*x.add(l)) };
                for (a, w) in acc.iter_mut().zip(&w) {
                    *a = _mm256_fmadd_pd(x, *w, *a);
                }
            }
        }
    }
}

#[derive(Clone, Debug)]
pub struct Mlp {
    sizes: Vec<usize>,
    layers: Vec<Linear>,
}

/// Hidden-activation buffers of an [`Mlp`] evaluation in scalar type `S`, as
/// interleaved [`Scalar::LANES`] components (`h[j * LANES + l]`).
#[derive(Clone, Debug)]
pub struct MlpScratch<S> {
    front: Vec<f64>,
    back: Vec<f64>,
    scalar: PhantomData<S>,
}

impl<S: Scalar> MlpScratch<S> {
    pub fn new(mlp: &Mlp) -> Self {
        let widest_output = mlp.layers.iter().map(|l| l.padded_outputs).max();
        let width = mlp.sizes[0].max(widest_output.unwrap_or(0));
        Self {
            front: vec![0.0; S::LANES * width],
            back: vec![0.0; S::LANES * width],
            scalar: PhantomData,
        }
    }
}

impl Mlp {
    pub fn from_weights(weights: &mut Weights, prefix: &str, sizes: &[usize]) -> FlowResult<Self> {
        let mut layers = Vec::with_capacity(sizes.len() - 1);
        for pair in mlp_parameter_shapes(prefix, sizes).chunks_exact(2) {
            let ((weight_name, weight_shape), (bias_name, bias_shape)) = (&pair[0], &pair[1]);
            let (outputs, inputs) = (weight_shape[0], weight_shape[1]);
            let weight = weights.take(weight_name, weight_shape)?;
            let bias = weights.take(bias_name, bias_shape)?;
            layers.push(Linear::new(&weight, &bias, inputs, outputs));
        }
        Ok(Self {
            sizes: sizes.to_vec(),
            layers,
        })
    }

    pub fn input_dim(&self) -> usize {
        self.sizes[0]
    }

    pub fn output_dim(&self) -> usize {
        self.sizes[self.sizes.len() - 1]
    }

    /// `out = MLP(input)`; allocation-free. On x86-64 CPUs with AVX2 and FMA the layers
    /// run on a 4-wide fused multiply-add kernel and the activations compile for 4-wide
    /// vectors (detected once, at run time).
    pub fn eval<S: Scalar>(&self, input: &[S], scratch: &mut MlpScratch<S>, out: &mut [S]) {
        with_simd(|simd| self.eval_with(simd, input, scratch, out, None))
    }

    /// Length of the record [`eval_recorded`](Self::eval_recorded) keeps.
    pub fn record_len(&self) -> usize {
        self.hidden_layers().map(|l| l.padded_outputs).sum()
    }

    /// [`eval`](Self::eval) in `f64` that keeps the hidden activations `h_j` in `record`
    /// (of [`record_len`](Self::record_len)) for [`tangent`](Self::tangent).
    pub fn eval_recorded(
        &self,
        input: &[f64],
        scratch: &mut MlpScratch<f64>,
        out: &mut [f64],
        record: &mut [f64],
    ) {
        with_simd(|simd| self.eval_with(simd, input, scratch, out, Some(record)))
    }

    /// The Jacobian-vector product `dout = ∂MLP/∂x · dx` at the input of the
    /// [`eval_recorded`](Self::eval_recorded) call that wrote `record`:
    /// `dh_{j+1} = (1 - h_{j+1}²) ⊙ (W_j dh_j)`, `dout = W_last dh`. One matrix-vector
    /// product per layer and no `tanh`, half the work of a dual-number pass.
    pub fn tangent(
        &self,
        record: &[f64],
        dx: &[f64],
        scratch: &mut MlpScratch<f64>,
        dout: &mut [f64],
    ) {
        with_simd(|simd| self.tangent_with(simd, record, dx, scratch, dout))
    }

    fn hidden_layers(&self) -> impl Iterator<Item = &Linear> {
        self.layers[..self.layers.len() - 1].iter()
    }

    #[inline(always)]
    fn eval_with<S: Scalar>(
        &self,
        simd: Simd,
        input: &[S],
        scratch: &mut MlpScratch<S>,
        out: &mut [S],
        mut record: Option<&mut [f64]>,
    ) {
        let lanes = S::LANES;
        let MlpScratch { front, back, .. } = scratch;
        for (v, x) in input.iter().zip(front.chunks_exact_mut(lanes)) {
            for (l, x) in x.iter_mut().enumerate() {
                *x = v.lane(l);
            }
        }
        let (last, hidden) = self.layers.split_last().expect("an MLP has a layer");
        for layer in hidden {
            layer.apply(front, lanes, true, back, simd);
            let h = &mut back[..layer.padded_outputs * lanes];
            for h in h.chunks_exact_mut(lanes) {
                let t = S::from_lanes(|l| h[l]).tanh();
                for (l, h) in h.iter_mut().enumerate() {
                    *h = t.lane(l);
                }
            }
            if let Some(rest) = record.take() {
                let (kept, rest) = rest.split_at_mut(layer.padded_outputs);
                for (k, h) in kept.iter_mut().zip(h.chunks_exact(lanes)) {
                    *k = h[0];
                }
                record = Some(rest);
            }
            std::mem::swap(front, back);
        }
        last.apply(front, lanes, true, back, simd);
        for (o, y) in out.iter_mut().zip(back.chunks_exact(lanes)) {
            *o = S::from_lanes(|l| y[l]);
        }
    }

    #[inline(always)]
    fn tangent_with(
        &self,
        simd: Simd,
        record: &[f64],
        dx: &[f64],
        scratch: &mut MlpScratch<f64>,
        dout: &mut [f64],
    ) {
        let MlpScratch { front, back, .. } = scratch;
        front[..dx.len()].copy_from_slice(dx);
        let (last, hidden) = self.layers.split_last().expect("an MLP has a layer");
        let mut record = record;
        for layer in hidden {
            layer.apply(front, 1, false, back, simd);
            let (h, rest) = record.split_at(layer.padded_outputs);
            for (d, h) in back.iter_mut().zip(h) {
                *d *= 1.0 - h * h;
            }
            record = rest;
            std::mem::swap(front, back);
        }
        last.apply(front, 1, false, back, simd);
        dout.copy_from_slice(&back[..dout.len()]);
    }
}

/// Runs `f` with the best instruction set of this CPU; for AVX2 + FMA, `f` is inlined into
/// a function compiled for them, so its loops vectorise with fused multiply-adds.
#[inline(always)]
fn with_simd<R>(f: impl FnOnce(Simd) -> R) -> R {
    #[cfg(target_arch = "x86_64")]
    if Simd::detect() == Simd::Avx2Fma {
        #[target_feature(enable = "avx2,fma")]
        fn avx2_fma<R>(f: impl FnOnce(Simd) -> R) -> R {
            f(Simd::Avx2Fma)
        }
        // SAFETY: AVX2 and FMA support were detected.
        return unsafe { avx2_fma(f) };
    }
    f(Simd::Portable)
}
