//! Multilayer perceptron `h_{j+1} = tanh(W_j h_j + b_j)`, linear last layer.
//!
//! `tanh` keeps the network smooth (the acceleration feed-forward differentiates it twice)
//! and its Jacobian bounded.
//!
//! The weights dominate the cost: a 2×64 conditioner holds ~40 KiB of them, so ten
//! layers do not fit in the L1 cache and every pass streams them in again. Everything is
//! therefore arranged to load each weight once per sweep and use it as often as possible:
//! dual-number activations are split into planes of their `f64` components
//! ([`Scalar::LANES`]) so `W` multiplies the values and all their derivative parts at
//! once, and [`Mlp::eval_and_tangent`] evaluates one point and a Jacobian-vector product
//! at another (recorded) point in the same sweep.

use std::marker::PhantomData;
use std::ops::Range;

use super::error::FlowResult;
use super::scalar::{Dual, Scalar, tanh_with};
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

    /// `out_l = W x_l + [l = 0 and with_bias] b` for `lanes` component planes: plane `l`
    /// of `x` holds `inputs` values at `l * stride`, plane `l` of `out` receives
    /// `padded_outputs` values at `l * stride`.
    ///
    /// The bias is a constant, so it enters the primal component only. `epilogue` follows
    /// on the outputs.
    fn apply(
        &self,
        planes: Planes,
        x: &[f64],
        out: &mut [f64],
        with_bias: bool,
        epilogue: Epilogue,
        simd: Simd,
    ) {
        let Planes { lanes, stride } = planes;
        assert!(
            lanes > 0
                && self.inputs.max(self.padded_outputs) <= stride
                && x.len() >= lanes * stride
                && out.len() >= lanes * stride,
            "activation planes too small for the layer"
        );
        match simd {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `Simd::Avx2Fma` is only chosen once both features were detected, and
            // the planes were just checked.
            Simd::Avx2Fma => unsafe { avx2::apply(self, planes, x, out, with_bias, epilogue) },
            Simd::Portable => {
                self.apply_portable(planes, x, out, with_bias);
                epilogue.apply(simd, planes, out, 0..self.padded_outputs);
            }
        }
    }

    fn apply_portable(&self, planes: Planes, x: &[f64], out: &mut [f64], with_bias: bool) {
        let Planes { lanes, stride } = planes;
        for l in 0..lanes {
            let out = &mut out[l * stride..][..self.padded_outputs];
            if with_bias && l == 0 {
                out.copy_from_slice(&self.bias);
            } else {
                out.fill(0.0);
            }
            let x = &x[l * stride..][..self.inputs];
            for (first, width, panel) in self.panels() {
                let out = &mut out[first..first + width];
                for (w, x) in panel.chunks_exact(width).zip(x) {
                    for (o, w) in out.iter_mut().zip(w) {
                        *o += x * w;
                    }
                }
            }
        }
    }
}

/// Activations as `lanes` planes of `stride` values (plane `l`: component `l`).
#[derive(Clone, Copy, Debug)]
struct Planes {
    lanes: usize,
    stride: usize,
}

/// What a layer applies to its outputs. The SIMD kernel runs it on each block of outputs
/// as soon as the block is complete, so the activation's arithmetic overlaps the loads of
/// the next block's weights.
#[derive(Clone, Copy, Debug)]
enum Epilogue<'a> {
    /// Nothing: the linear output layer, or activations of more than two lanes (done by
    /// the caller).
    None,
    /// `h ← tanh(h)` in plane 0 and, for `Dual<f64>` (`dual`), `ḣ ← (1 - h²) ḣ` in plane 1.
    Tanh { dual: bool },
    /// The tangent `ḣ ← (1 - r²) ḣ` in the last plane, with `r` the recorded activations,
    /// and `h ← tanh(h)` in plane 0 when it holds a `primal` point.
    Tangent { record: &'a [f64], primal: bool },
}

impl Epilogue<'_> {
    /// Applies to outputs `range` of the planes `h`.
    #[inline(always)]
    fn apply(self, simd: Simd, planes: Planes, h: &mut [f64], range: Range<usize>) {
        let (values, rest) = h.split_at_mut(planes.stride);
        match self {
            Self::None => {}
            Self::Tanh { dual: false } => {
                for v in &mut values[range] {
                    *v = simd.tanh(*v);
                }
            }
            Self::Tanh { dual: true } => {
                for (v, d) in values[range.clone()].iter_mut().zip(&mut rest[range]) {
                    let t = simd.tanh(*v);
                    *v = t;
                    *d *= 1.0 - t * t;
                }
            }
            Self::Tangent {
                record,
                primal: false,
            } => {
                for (d, r) in values[range.clone()].iter_mut().zip(&record[range]) {
                    *d *= 1.0 - r * r;
                }
            }
            Self::Tangent {
                record,
                primal: true,
            } => {
                let tangents = rest[range.clone()].iter_mut().zip(&record[range.clone()]);
                for (v, (d, r)) in values[range].iter_mut().zip(tangents) {
                    *v = simd.tanh(*v);
                    *d *= 1.0 - r * r;
                }
            }
        }
    }
}

/// Which instruction set the layers run on.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Simd {
    Portable,
    #[cfg(target_arch = "x86_64")]
    Avx2Fma,
}

impl Simd {
    fn detect() -> Self {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
        {
            return Self::Avx2Fma;
        }
        Self::Portable
    }

    /// `tanh(x)`, with fused multiply-adds where they are single instructions.
    #[inline(always)]
    fn tanh(self, x: f64) -> f64 {
        if self == Self::Portable {
            tanh_with::<false>(x)
        } else {
            tanh_with::<true>(x)
        }
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

    use super::{Epilogue, Linear, NARROW, Planes, Simd, WIDE};

    /// # Safety
    /// The CPU supports AVX2 and FMA; `x` and `out` hold `planes.lanes` planes of
    /// `planes.stride >= max(inputs, padded_outputs)` values.
    #[target_feature(enable = "avx2,fma")]
    pub(super) unsafe fn apply(
        linear: &Linear,
        planes: Planes,
        x: &[f64],
        out: &mut [f64],
        with_bias: bool,
        epilogue: Epilogue,
    ) {
        // SAFETY (all blocks): the caller's guarantee and the panel layout of
        // `Linear::new` keep every access in bounds.
        unsafe {
            match planes.lanes {
                1 => lane_group::<1, 8, 4>(linear, planes, 0, x, out, with_bias, epilogue),
                2 => lane_group::<2, 4, 2>(linear, planes, 0, x, out, with_bias, epilogue),
                lanes => {
                    if lanes % 4 == 0 {
                        for first in (0..lanes).step_by(4) {
                            let none = Epilogue::None;
                            lane_group::<4, 2, 1>(linear, planes, first, x, out, with_bias, none);
                        }
                    } else {
                        linear.apply_portable(planes, x, out, with_bias);
                    }
                    let all = 0..linear.padded_outputs;
                    epilogue.apply(Simd::Avx2Fma, planes, out, all);
                }
            }
        }
    }

    /// Lanes `first..first + L`: blocks of `4 V` outputs of the wide panels, then the
    /// narrow panels with `SPLIT` partial sums; `epilogue` after each block.
    #[target_feature(enable = "avx2,fma")]
    unsafe fn lane_group<const L: usize, const V: usize, const SPLIT: usize>(
        linear: &Linear,
        planes: Planes,
        first: usize,
        x: &[f64],
        out: &mut [f64],
        with_bias: bool,
        epilogue: Epilogue,
    ) {
        let stride = planes.stride;
        let bias = (with_bias && first == 0).then_some(linear.bias.as_ptr());
        let inputs = linear.inputs;
        let x = unsafe { x.as_ptr().add(first * stride) };
        let panels = linear.panels.as_ptr();
        for start in (0..linear.wide_outputs).step_by(4 * V) {
            let panel_start = start - start % WIDE;
            let weights = unsafe { panels.add(panel_start * inputs + start - panel_start) };
            let block = Block::<WIDE> {
                weights,
                inputs,
                x,
                stride,
            };
            let at = unsafe { out.as_mut_ptr().add(first * stride + start) };
            unsafe { block.run::<L, V, 1>(bias.map(|b| b.add(start)), at) };
            epilogue.apply(Simd::Avx2Fma, planes, out, start..start + 4 * V);
        }
        for start in (linear.wide_outputs..linear.padded_outputs).step_by(NARROW) {
            let weights = unsafe { panels.add(start * inputs) };
            let block = Block::<NARROW> {
                weights,
                inputs,
                x,
                stride,
            };
            let at = unsafe { out.as_mut_ptr().add(first * stride + start) };
            unsafe { block.run::<L, { NARROW / 4 }, SPLIT>(bias.map(|b| b.add(start)), at) };
            epilogue.apply(Simd::Avx2Fma, planes, out, start..start + NARROW);
        }
    }

    /// A block of outputs: `weights` points at its first column in a panel of width `W`,
    /// `x` at input 0 of the first lane, lane `l` at `x + l * stride`.
    struct Block<const W: usize> {
        weights: *const f64,
        inputs: usize,
        x: *const f64,
        stride: usize,
    }

    impl<const W: usize> Block<W> {
        /// `out[l * stride + o] = Σ_i w[i][o] x[l * stride + i] (+ bias[o] for l = 0)` for
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
                for (t, p) in total
                    .as_flattened_mut()
                    .iter_mut()
                    .zip(partial.as_flattened())
                {
                    *t = _mm256_add_pd(*t, *p);
                }
            }
            for (l, lane) in total.iter().enumerate() {
                for (v, t) in lane.iter().enumerate() {
                    unsafe { _mm256_storeu_pd(out.add(l * self.stride + 4 * v), *t) };
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
            for (l, acc) in acc.iter_mut().enumerate() {
                let x = unsafe { _mm256_broadcast_sd(&*self.x.add(l * self.stride + input)) };
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

/// Activation buffers of an [`Mlp`] evaluation in scalar type `S`: planes of its
/// [`Scalar::LANES`] components.
#[derive(Clone, Debug)]
pub struct MlpScratch<S> {
    front: Vec<f64>,
    back: Vec<f64>,
    stride: usize,
    scalar: PhantomData<S>,
}

impl<S: Scalar> MlpScratch<S> {
    pub fn new(mlp: &Mlp) -> Self {
        let widest_output = mlp.layers.iter().map(|l| l.padded_outputs).max();
        let stride = mlp.sizes[0].max(widest_output.unwrap_or(0));
        Self {
            front: vec![0.0; S::LANES * stride],
            back: vec![0.0; S::LANES * stride],
            stride,
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
        self.eval_dispatch(input, scratch, out, None)
    }

    /// Length of the record [`eval_recorded`](Self::eval_recorded) keeps.
    pub fn record_len(&self) -> usize {
        self.layers[..self.layers.len() - 1]
            .iter()
            .map(|l| l.padded_outputs)
            .sum()
    }

    /// [`eval`](Self::eval) that keeps the (primal) hidden activations `h_j` in `record`
    /// (of [`record_len`](Self::record_len)) for [`tangent`](Self::tangent).
    pub fn eval_recorded<S: Scalar>(
        &self,
        input: &[S],
        scratch: &mut MlpScratch<S>,
        out: &mut [S],
        record: &mut [f64],
    ) {
        self.eval_dispatch(input, scratch, out, Some(record))
    }

    /// The Jacobian-vector product `dout = ∂MLP/∂x · dx` at the input of the
    /// [`eval_recorded`](Self::eval_recorded) call that wrote `record`:
    /// `dh_{j+1} = (1 - h_{j+1}²) ⊙ (W_j dh_j)`, `dout = W_last dh`. One matrix-vector
    /// product per layer and no `tanh`, half the work of a dual-number pass.
    pub fn tangent(
        &self,
        record: &[f64],
        dx: &[f64],
        scratch: &mut MlpScratch<Dual<f64>>,
        dout: &mut [f64],
    ) {
        self.sweep_dispatch(record, dx, dout, None, scratch)
    }

    /// `out = MLP(input)` and the [`tangent`](Self::tangent) `dout` at the recorded point
    /// in one sweep over the weights: each layer multiplies both vectors at once.
    pub fn eval_and_tangent(
        &self,
        input: &[f64],
        out: &mut [f64],
        record: &[f64],
        dx: &[f64],
        dout: &mut [f64],
        scratch: &mut MlpScratch<Dual<f64>>,
    ) {
        self.sweep_dispatch(record, dx, dout, Some((input, out)), scratch)
    }

    /// Runs [`eval_with`](Self::eval_with) on the best instruction set of this CPU.
    fn eval_dispatch<S: Scalar>(
        &self,
        input: &[S],
        scratch: &mut MlpScratch<S>,
        out: &mut [S],
        record: Option<&mut [f64]>,
    ) {
        match Simd::detect() {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: AVX2 and FMA support were detected.
            Simd::Avx2Fma => unsafe { self.eval_avx2(input, scratch, out, record) },
            Simd::Portable => self.eval_with(Simd::Portable, input, scratch, out, record),
        }
    }

    /// [`eval_with`](Self::eval_with) compiled for AVX2 and FMA, so the activation loops
    /// vectorise too.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    fn eval_avx2<S: Scalar>(
        &self,
        input: &[S],
        scratch: &mut MlpScratch<S>,
        out: &mut [S],
        record: Option<&mut [f64]>,
    ) {
        self.eval_with(Simd::Avx2Fma, input, scratch, out, record)
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
        let planes = Planes {
            lanes: S::LANES,
            stride: scratch.stride,
        };
        let MlpScratch { front, back, .. } = scratch;
        for (j, v) in input.iter().enumerate() {
            for l in 0..planes.lanes {
                front[l * planes.stride + j] = v.lane(l);
            }
        }
        let (last, hidden) = self.layers.split_last().expect("an MLP has a layer");
        let epilogue = match planes.lanes {
            1 => Epilogue::Tanh { dual: false },
            2 => Epilogue::Tanh { dual: true },
            _ => Epilogue::None,
        };
        for layer in hidden {
            layer.apply(planes, front, back, true, epilogue, simd);
            let n = layer.padded_outputs;
            if planes.lanes > 2 {
                activate::<S>(planes, n, back);
            }
            if let Some(rest) = record.take() {
                let (kept, rest) = rest.split_at_mut(n);
                kept.copy_from_slice(&back[..n]);
                record = Some(rest);
            }
            std::mem::swap(front, back);
        }
        last.apply(planes, front, back, true, Epilogue::None, simd);
        for (j, o) in out.iter_mut().enumerate() {
            *o = S::from_lanes(|l| back[l * planes.stride + j]);
        }
    }

    /// Runs [`sweep_with`](Self::sweep_with) on the best instruction set of this CPU.
    fn sweep_dispatch(
        &self,
        record: &[f64],
        dx: &[f64],
        dout: &mut [f64],
        primal: Option<(&[f64], &mut [f64])>,
        scratch: &mut MlpScratch<Dual<f64>>,
    ) {
        match Simd::detect() {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: AVX2 and FMA support were detected.
            Simd::Avx2Fma => unsafe { self.sweep_avx2(record, dx, dout, primal, scratch) },
            Simd::Portable => self.sweep_with(Simd::Portable, record, dx, dout, primal, scratch),
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    fn sweep_avx2(
        &self,
        record: &[f64],
        dx: &[f64],
        dout: &mut [f64],
        primal: Option<(&[f64], &mut [f64])>,
        scratch: &mut MlpScratch<Dual<f64>>,
    ) {
        self.sweep_with(Simd::Avx2Fma, record, dx, dout, primal, scratch)
    }

    /// The tangent along `dx` at the recorded point, in the last plane, and when `primal`
    /// is given its evaluation in plane 0.
    #[inline(always)]
    fn sweep_with(
        &self,
        simd: Simd,
        record: &[f64],
        dx: &[f64],
        dout: &mut [f64],
        primal: Option<(&[f64], &mut [f64])>,
        scratch: &mut MlpScratch<Dual<f64>>,
    ) {
        let with_primal = primal.is_some();
        let planes = Planes {
            lanes: 1 + usize::from(with_primal),
            stride: scratch.stride,
        };
        let tangent = (planes.lanes - 1) * planes.stride;
        let MlpScratch { front, back, .. } = scratch;
        front[tangent..tangent + dx.len()].copy_from_slice(dx);
        if let Some((input, _)) = &primal {
            front[..input.len()].copy_from_slice(input);
        }
        let (last, hidden) = self.layers.split_last().expect("an MLP has a layer");
        let mut record = record;
        for layer in hidden {
            let (h, rest) = record.split_at(layer.padded_outputs);
            let epilogue = Epilogue::Tangent {
                record: h,
                primal: with_primal,
            };
            layer.apply(planes, front, back, with_primal, epilogue, simd);
            record = rest;
            std::mem::swap(front, back);
        }
        last.apply(planes, front, back, with_primal, Epilogue::None, simd);
        dout.copy_from_slice(&back[tangent..tangent + dout.len()]);
        if let Some((_, out)) = primal {
            out.copy_from_slice(&back[..out.len()]);
        }
    }
}

/// `h ← tanh(h)` on the first `n` entries of the component planes `h`, for scalars of
/// more than two lanes (nested duals; one and two lanes are the layers' [`Epilogue`]).
#[inline(always)]
fn activate<S: Scalar>(planes: Planes, n: usize, h: &mut [f64]) {
    for j in 0..n {
        let t = S::from_lanes(|l| h[l * planes.stride + j]).tanh();
        for l in 0..planes.lanes {
            h[l * planes.stride + j] = t.lane(l);
        }
    }
}

#[cfg(test)]
mod tests {
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    use super::*;

    type Dual2 = Dual<Dual<f64>>;

    /// Odd sizes so both panel widths, the padding and the partial-sum tails are used.
    fn random_mlp(sizes: &[usize], seed: u64) -> Mlp {
        let shapes = mlp_parameter_shapes("net", sizes);
        let mut weights = Weights::random(&shapes, 1.0, &mut ChaCha8Rng::seed_from_u64(seed));
        Mlp::from_weights(&mut weights, "net", sizes).unwrap()
    }

    fn inputs<S: Scalar>(n: usize, offset: f64) -> Vec<S> {
        (0..n)
            .map(|i| S::from_lanes(|l| ((i * 7 + l * 3) as f64 * 0.37 + offset).sin()))
            .collect()
    }

    fn assert_close<S: Scalar>(a: &[S], b: &[S], tolerance: f64) {
        for (a, b) in a.iter().zip(b) {
            for l in 0..S::LANES {
                let (x, y) = (a.lane(l), b.lane(l));
                assert!((x - y).abs() <= tolerance * (1.0 + y.abs()), "{x} vs {y}");
            }
        }
    }

    /// The best kernel of this CPU against the portable one, in `S`.
    fn check_kernels<S: Scalar>(mlp: &Mlp) {
        let x = inputs::<S>(mlp.input_dim(), 0.1);
        let mut scratch = MlpScratch::new(mlp);
        let zero = S::constant(0.0);
        let (mut fast, mut portable) = (vec![zero; mlp.output_dim()], vec![zero; mlp.output_dim()]);
        mlp.eval(&x, &mut scratch, &mut fast);
        mlp.eval_with(Simd::Portable, &x, &mut scratch, &mut portable, None);
        assert_close(&fast, &portable, 1e-12);
    }

    #[test]
    fn simd_kernel_matches_the_portable_one_for_every_lane_count() {
        for (k, sizes) in [[5, 37, 70, 13], [9, 64, 64, 92], [2, 8, 3, 1]]
            .iter()
            .enumerate()
        {
            let mlp = random_mlp(sizes, k as u64);
            check_kernels::<f64>(&mlp);
            check_kernels::<Dual<f64>>(&mlp);
            check_kernels::<Dual2>(&mlp);
            check_kernels::<Dual<Dual2>>(&mlp);
        }
    }

    #[test]
    fn recorded_tangents_match_dual_numbers() {
        let mlp = random_mlp(&[6, 37, 70, 13], 7);
        let (n, m) = (mlp.input_dim(), mlp.output_dim());
        let (x, dx, other) = (
            inputs::<f64>(n, 0.1),
            inputs::<f64>(n, 2.0),
            inputs::<f64>(n, 4.0),
        );
        let mut record = vec![0.0; mlp.record_len()];
        let mut scratch = MlpScratch::new(&mlp);
        let mut out = vec![0.0; m];
        mlp.eval_recorded(&x, &mut scratch, &mut out, &mut record);

        let duals: Vec<Dual<f64>> = x.iter().zip(&dx).map(|(a, b)| Dual::new(*a, *b)).collect();
        let mut expected = vec![Dual::new(0.0, 0.0); m];
        mlp.eval(&duals, &mut MlpScratch::new(&mlp), &mut expected);
        let expected_tangent: Vec<f64> = expected.iter().map(|d| d.du).collect();
        assert_close(
            &out,
            &expected.iter().map(|d| d.re).collect::<Vec<_>>(),
            1e-12,
        );

        let mut pair_scratch = MlpScratch::new(&mlp);
        let mut tangent = vec![0.0; m];
        mlp.tangent(&record, &dx, &mut pair_scratch, &mut tangent);
        assert_close(&tangent, &expected_tangent, 1e-12);

        let (mut other_out, mut fused_tangent) = (vec![0.0; m], vec![0.0; m]);
        mlp.eval_and_tangent(
            &other,
            &mut other_out,
            &record,
            &dx,
            &mut fused_tangent,
            &mut pair_scratch,
        );
        let mut other_expected = vec![0.0; m];
        mlp.eval(&other, &mut scratch, &mut other_expected);
        assert_close(&other_out, &other_expected, 1e-12);
        assert_close(&fused_tangent, &expected_tangent, 1e-12);
    }
}
