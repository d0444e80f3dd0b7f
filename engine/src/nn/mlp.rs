//! Multilayer perceptron `h_{j+1} = tanh(W_j h_j + b_j)`, linear last layer.
//!
//! `tanh` keeps the network smooth (the acceleration feed-forward differentiates it twice)
//! and its Jacobian bounded.
//!
//! The weights dominate the cost: a 2×64 conditioner holds ~20 KiB of them, so ten
//! layers do not fit in the L1 cache and every pass streams them in again. Everything is
//! therefore arranged to load each weight once per sweep and use it as often as possible:
//! dual-number activations are split into planes of their `f64` components
//! ([`Scalar::LANES`]) so `W` multiplies the values and all their derivative parts at
//! once, and [`Mlp::eval_and_tangent`] evaluates one point and a Jacobian-vector product
//! at another (recorded) point in the same sweep.
//!
//! A recorded evaluation also spares later passes at the same point their `tanh` and
//! their value planes: [`Mlp::tangent`] sweeps one plane and [`Mlp::second_tangent`] (the
//! policy's acceleration) two, where a dual-number pass would sweep two and four.
//!
//! The weights are kept in `f32` and widened as they are loaded; activations, biases and
//! sums stay `f64`. Halving the bytes streamed per sweep took the pouring policy's action
//! from 19.6 to 14.3 µs (`cargo bench --bench flow`); rounding the trained weights to
//! `f32` moves the outputs by about 1e-8 relative, far inside the 1e-5 of the parity test
//! against tch (`engine/train/tests/parity.rs`). Rounding the activations and summing in
//! `f32` as well (8-wide) was tried and not kept: 14 % off the action, but the flows
//! amplify the rounding past 1e-4 relative in their actions (`bench/README.md`, "One
//! policy action").

use std::marker::PhantomData;

use crate::flow::checkpoint::names::{self, BIAS, WEIGHT};
use crate::flow::checkpoint::weights::Weights;
use crate::flow::error::FlowResult;
use crate::math::simd::Simd;
use crate::nn::scalar::{Dual, Scalar, tanh_with};

/// Names and shapes `{prefix}.{j}.weight: [out, in]`, `{prefix}.{j}.bias: [out]`, as
/// `tch::nn::linear` creates them.
pub fn mlp_parameter_shapes(prefix: &str, sizes: &[usize]) -> Vec<(String, Vec<usize>)> {
    sizes
        .windows(2)
        .enumerate()
        .flat_map(|(j, io)| {
            [
                (names::name(&[&prefix, &j, &WEIGHT]), vec![io[1], io[0]]),
                (names::name(&[&prefix, &j, &BIAS]), vec![io[1]]),
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
    /// `W` (rounded to `f32`) in panels: the panel of outputs `o..o + width` holds
    /// `[inputs][width]` at `o * inputs`, the weights input after input, so a block of
    /// outputs streams through contiguous memory. [`WIDE`] panels first, then [`NARROW`]
    /// ones for the rest.
    panels: Vec<f32>,
    /// `b`, zero-padded to `padded_outputs`.
    bias: Vec<f64>,
}

/// Outputs per wide weight panel (eight 4-wide or four 8-wide vectors).
const WIDE: usize = 32;
/// Outputs per narrow weight panel (two 4-wide vectors or one 8-wide), and the padding
/// unit.
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
                linear.panels[first * inputs + i * width + o - first] = *w as f32;
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
    fn panels<'a>(&'a self) -> impl Iterator<Item = (usize, usize, &'a [f32])> {
        let (wide, narrow) = self.panels.split_at(self.wide_outputs * self.inputs);
        let inputs = self.inputs;
        let panels = move |weights: &'a [f32], width: usize, offset: usize| {
            weights
                .chunks_exact(width * inputs)
                .enumerate()
                .map(move |(q, w)| (offset + q * width, width, w))
        };
        panels(wide, WIDE, 0).chain(panels(narrow, NARROW, self.wide_outputs))
    }

    /// `out_l = W[:, ..inputs] x_l + [l = 0] bias` for `lanes` component planes: plane `l`
    /// of `x` holds `inputs` values at `l * stride`, plane `l` of `out` receives
    /// `padded_outputs` values at `l * stride`. Inputs past `inputs` are taken as fixed
    /// and folded into `bias` ([`Mlp::fold_trailing_inputs`]).
    ///
    /// The bias is a constant, so it enters the primal component only (`None`: tangents).
    fn apply(
        &self,
        planes: Planes,
        x: &[f64],
        out: &mut [f64],
        layer_input: LayerInput,
        simd: Simd,
    ) {
        let Planes { lanes, stride } = planes;
        assert!(
            lanes > 0
                && layer_input.inputs <= self.inputs
                && layer_input
                    .bias
                    .is_none_or(|b| b.len() >= self.padded_outputs)
                && self.inputs.max(self.padded_outputs) <= stride
                && x.len() >= lanes * stride
                && out.len() >= lanes * stride,
            "activation planes too small for the layer"
        );
        match simd {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: a kernel is only chosen once its features were detected, and the
            // planes were just checked.
            Simd::Avx2Fma => unsafe { kernel::apply_avx2(self, planes, x, out, layer_input) },
            #[cfg(target_arch = "x86_64")]
            // SAFETY: as above.
            Simd::Avx512 => unsafe { kernel::apply_avx512(self, planes, x, out, layer_input) },
            Simd::Portable => self.apply_portable(planes, x, out, layer_input),
        }
    }

    fn apply_portable(&self, planes: Planes, x: &[f64], out: &mut [f64], input: LayerInput) {
        let Planes { lanes, stride } = planes;
        for l in 0..lanes {
            let out = &mut out[l * stride..][..self.padded_outputs];
            match input.bias {
                Some(bias) if l == 0 => out.copy_from_slice(&bias[..self.padded_outputs]),
                _ => out.fill(0.0),
            }
            let x = &x[l * stride..][..input.inputs];
            for (first, width, panel) in self.panels() {
                let out = &mut out[first..first + width];
                for (w, x) in panel.chunks_exact(width).zip(x) {
                    for (o, w) in out.iter_mut().zip(w) {
                        *o += x * f64::from(*w);
                    }
                }
            }
        }
    }

    /// The whole layer with its own bias.
    fn full_input(&self) -> LayerInput<'_> {
        LayerInput {
            inputs: self.inputs,
            bias: Some(&self.bias),
        }
    }
}

/// What a layer evaluation reads: its leading `inputs` inputs, and the primal plane's
/// bias (padded like the layer's outputs; `None` for tangents).
#[derive(Clone, Copy, Debug)]
struct LayerInput<'a> {
    inputs: usize,
    bias: Option<&'a [f64]>,
}

/// Activations as `lanes` planes of `stride` values (plane `l`: component `l`).
#[derive(Clone, Copy, Debug)]
struct Planes {
    lanes: usize,
    stride: usize,
}

/// `tanh(x)`, with fused multiply-adds where `simd` has them as single instructions.
#[inline(always)]
fn tanh(simd: Simd, x: f64) -> f64 {
    if simd.fused() {
        tanh_with::<true>(x)
    } else {
        tanh_with::<false>(x)
    }
}

/// The SIMD kernels of [`Linear::apply`]: one body, compiled for AVX2 + FMA (registers of
/// four `f64`) and for AVX-512 (eight).
///
/// Blocks of outputs accumulate in registers while the inputs stream by, about eight
/// accumulators at a time so the fused multiply-add latency stays hidden (two pipes, four
/// cycles each): for `L` lanes at a time, blocks of `V` registers of outputs of the wide
/// panels with their inputs split into `P` interleaved partial sums, then the narrow
/// panels (`VN` registers) with `PN`. The weights of a block are loaded and widened once
/// for all lanes.
///
/// AVX-512 halves the instructions per multiply-add. On this project's VMs (AMD Zen 5,
/// 512-bit operations at full width) it and the activations' 8-wide loops took the
/// pouring-sized action with 2×64 conditioners from 12.2–12.8 to 8.0–8.5 µs
/// (`cargo bench --bench flow`, `bench/README.md`).
#[cfg(target_arch = "x86_64")]
mod kernel {
    use std::arch::x86_64::*;

    use super::{LayerInput, Linear, NARROW, Planes, WIDE};

    /// A register of `WIDTH` `f64` lanes and the operations the kernel needs. Its
    /// methods are inlined into functions compiled for the register's instruction set,
    /// and only called there.
    trait Register: Copy {
        const WIDTH: usize;
        /// # Safety (all methods)
        /// The CPU has the register's instruction set; pointers are valid for `WIDTH`
        /// values (`splat`: one).
        unsafe fn zero() -> Self;
        unsafe fn load(from: *const f64) -> Self;
        /// `WIDTH` `f32` widened to `f64`.
        unsafe fn load_widened(from: *const f32) -> Self;
        /// `*from` in every lane.
        unsafe fn splat(from: *const f64) -> Self;
        /// `self · w + acc`, fused.
        unsafe fn mul_add(self, w: Self, acc: Self) -> Self;
        unsafe fn add(self, other: Self) -> Self;
        unsafe fn store(self, to: *mut f64);
    }

    impl Register for __m256d {
        const WIDTH: usize = 4;
        #[inline(always)]
        unsafe fn zero() -> Self {
            unsafe { _mm256_setzero_pd() }
        }
        #[inline(always)]
        unsafe fn load(from: *const f64) -> Self {
            unsafe { _mm256_loadu_pd(from) }
        }
        #[inline(always)]
        unsafe fn load_widened(from: *const f32) -> Self {
            unsafe { _mm256_cvtps_pd(_mm_loadu_ps(from)) }
        }
        #[inline(always)]
        unsafe fn splat(from: *const f64) -> Self {
            unsafe { _mm256_broadcast_sd(&*from) }
        }
        #[inline(always)]
        unsafe fn mul_add(self, w: Self, acc: Self) -> Self {
            unsafe { _mm256_fmadd_pd(self, w, acc) }
        }
        #[inline(always)]
        unsafe fn add(self, other: Self) -> Self {
            unsafe { _mm256_add_pd(self, other) }
        }
        #[inline(always)]
        unsafe fn store(self, to: *mut f64) {
            unsafe { _mm256_storeu_pd(to, self) }
        }
    }

    impl Register for __m512d {
        const WIDTH: usize = 8;
        #[inline(always)]
        unsafe fn zero() -> Self {
            unsafe { _mm512_setzero_pd() }
        }
        #[inline(always)]
        unsafe fn load(from: *const f64) -> Self {
            unsafe { _mm512_loadu_pd(from) }
        }
        #[inline(always)]
        unsafe fn load_widened(from: *const f32) -> Self {
            unsafe { _mm512_cvtps_pd(_mm256_loadu_ps(from)) }
        }
        #[inline(always)]
        unsafe fn splat(from: *const f64) -> Self {
            unsafe { _mm512_set1_pd(*from) }
        }
        #[inline(always)]
        unsafe fn mul_add(self, w: Self, acc: Self) -> Self {
            unsafe { _mm512_fmadd_pd(self, w, acc) }
        }
        #[inline(always)]
        unsafe fn add(self, other: Self) -> Self {
            unsafe { _mm512_add_pd(self, other) }
        }
        #[inline(always)]
        unsafe fn store(self, to: *mut f64) {
            unsafe { _mm512_storeu_pd(to, self) }
        }
    }

    /// # Safety
    /// The CPU supports AVX2 and FMA; `x` and `out` hold `planes.lanes` planes of
    /// `planes.stride >= max(inputs, padded_outputs)` values.
    #[target_feature(enable = "avx2,fma")]
    pub(crate) unsafe fn apply_avx2(
        linear: &Linear,
        planes: Planes,
        x: &[f64],
        out: &mut [f64],
        input: LayerInput,
    ) {
        // SAFETY (all blocks): the caller's guarantee and the panel layout of
        // `Linear::new` keep every access in bounds.
        unsafe {
            match planes.lanes {
                1 => lane_group::<__m256d, 1, 8, 1, 2, 4>(linear, planes, 0, x, out, input),
                2 => lane_group::<__m256d, 2, 4, 1, 2, 2>(linear, planes, 0, x, out, input),
                lanes if lanes % 4 == 0 => {
                    for first in (0..lanes).step_by(4) {
                        lane_group::<__m256d, 4, 2, 1, 2, 1>(linear, planes, first, x, out, input);
                    }
                }
                _ => linear.apply_portable(planes, x, out, input),
            }
        }
    }

    /// # Safety
    /// As [`apply_avx2`], with AVX-512F.
    #[target_feature(enable = "avx512f")]
    pub(crate) unsafe fn apply_avx512(
        linear: &Linear,
        planes: Planes,
        x: &[f64],
        out: &mut [f64],
        input: LayerInput,
    ) {
        // SAFETY: as in `apply_avx2`.
        unsafe {
            match planes.lanes {
                1 => lane_group::<__m512d, 1, 4, 2, 1, 8>(linear, planes, 0, x, out, input),
                2 => lane_group::<__m512d, 2, 4, 1, 1, 4>(linear, planes, 0, x, out, input),
                lanes if lanes % 4 == 0 => {
                    for first in (0..lanes).step_by(4) {
                        lane_group::<__m512d, 4, 2, 1, 1, 2>(linear, planes, first, x, out, input);
                    }
                }
                _ => linear.apply_portable(planes, x, out, input),
            }
        }
    }

    /// Lanes `first..first + L`: blocks of `V` registers of outputs of the wide panels
    /// summed in `P` partial sums, then the narrow panels in `VN` registers and `PN`
    /// partial sums.
    #[inline(always)]
    unsafe fn lane_group<
        R: Register,
        const L: usize,
        const V: usize,
        const P: usize,
        const VN: usize,
        const PN: usize,
    >(
        linear: &Linear,
        planes: Planes,
        first: usize,
        x: &[f64],
        out: &mut [f64],
        input: LayerInput,
    ) {
        debug_assert!(WIDE.is_multiple_of(V * R::WIDTH) && VN * R::WIDTH == NARROW);
        let stride = planes.stride;
        let bias = input.bias.filter(|_| first == 0).map(<[f64]>::as_ptr);
        let (used, inputs) = (input.inputs, linear.inputs);
        let x = unsafe { x.as_ptr().add(first * stride) };
        let out = unsafe { out.as_mut_ptr().add(first * stride) };
        let panels = linear.panels.as_ptr();
        for start in (0..linear.wide_outputs).step_by(V * R::WIDTH) {
            let panel_start = start - start % WIDE;
            let weights = unsafe { panels.add(panel_start * inputs + start - panel_start) };
            let block = Block::<WIDE> {
                weights,
                inputs: used,
                x,
                stride,
            };
            unsafe { block.run::<R, L, V, P>(bias.map(|b| b.add(start)), out.add(start)) };
        }
        for start in (linear.wide_outputs..linear.padded_outputs).step_by(NARROW) {
            let weights = unsafe { panels.add(start * inputs) };
            let block = Block::<NARROW> {
                weights,
                inputs: used,
                x,
                stride,
            };
            unsafe { block.run::<R, L, VN, PN>(bias.map(|b| b.add(start)), out.add(start)) };
        }
    }

    /// A block of outputs: `weights` points at its first column in a panel of width `W`,
    /// `x` at input 0 of the first lane, lane `l` at `x + l * stride`.
    struct Block<const W: usize> {
        weights: *const f32,
        inputs: usize,
        x: *const f64,
        stride: usize,
    }

    impl<const W: usize> Block<W> {
        /// `out[l * stride + o] = Σ_i w[i][o] x[l * stride + i] (+ bias[o] for l = 0)` for
        /// `o < V · WIDTH`, `l < L`, the inputs summed in `P` interleaved partial sums.
        #[inline(always)]
        unsafe fn run<R: Register, const L: usize, const V: usize, const P: usize>(
            &self,
            bias: Option<*const f64>,
            out: *mut f64,
        ) {
            let mut acc = [[[unsafe { R::zero() }; V]; L]; P];
            if let Some(bias) = bias {
                for (v, a) in acc[0][0].iter_mut().enumerate() {
                    *a = unsafe { R::load(bias.add(R::WIDTH * v)) };
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
                    *t = unsafe { t.add(*p) };
                }
            }
            for (l, lane) in total.iter().enumerate() {
                for (v, t) in lane.iter().enumerate() {
                    unsafe { t.store(out.add(l * self.stride + R::WIDTH * v)) };
                }
            }
        }

        /// `acc_l += w[input] x_l[input]`.
        #[inline(always)]
        unsafe fn accumulate<R: Register, const L: usize, const V: usize>(
            &self,
            input: usize,
            acc: &mut [[R; V]; L],
        ) {
            let row = unsafe { self.weights.add(input * W) };
            let w: [R; V] =
                std::array::from_fn(|v| unsafe { R::load_widened(row.add(R::WIDTH * v)) });
            for (l, acc) in acc.iter_mut().enumerate() {
                let x = unsafe { R::splat(self.x.add(l * self.stride + input)) };
                for (a, w) in acc.iter_mut().zip(&w) {
                    *a = unsafe { x.mul_add(*w, *a) };
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
    /// vectors, 8-wide with AVX-512F (detected once, at run time).
    pub fn eval<S: Scalar>(&self, input: &[S], scratch: &mut MlpScratch<S>, out: &mut [S]) {
        let first = self.layers[0].full_input();
        self.eval_dispatch(input, first, scratch, out, None)
    }

    /// Length of the first-layer bias [`fold_trailing_inputs`](Self::fold_trailing_inputs)
    /// writes.
    pub fn folded_bias_len(&self) -> usize {
        self.layers[0].padded_outputs
    }

    /// `bias = b₀ + W₀[:, n - m..] t`: the first layer's bias with its last `m` inputs
    /// fixed to `t` (a context), so evaluations at many points with the same `t` read
    /// only the first `n - m` columns of `W₀` ([`eval_folded`](Self::eval_folded)).
    pub fn fold_trailing_inputs(&self, trailing: &[f64], bias: &mut [f64]) {
        let first = &self.layers[0];
        let head = first.inputs - trailing.len();
        bias[..first.padded_outputs].copy_from_slice(&first.bias);
        for (panel_first, width, panel) in first.panels() {
            let rows = panel.chunks_exact(width).skip(head);
            for (w, t) in rows.zip(trailing) {
                for (b, w) in bias[panel_first..panel_first + width].iter_mut().zip(w) {
                    *b += t * f64::from(*w);
                }
            }
        }
    }

    /// Length of the record [`eval_folded`](Self::eval_folded) keeps per component
    /// ([`Scalar::LANES`]) of its scalar type.
    pub fn record_len(&self) -> usize {
        self.layers[..self.layers.len() - 1]
            .iter()
            .map(|l| l.padded_outputs)
            .sum()
    }

    /// `out = MLP([head, t])` with the trailing inputs `t` folded into `first_bias`
    /// ([`fold_trailing_inputs`](Self::fold_trailing_inputs)); keeps the hidden
    /// activations in `record` (`S::LANES ×` [`record_len`](Self::record_len), layer by
    /// layer, each layer's component planes in turn) when given, for
    /// [`tangent`](Self::tangent) (`f64`) or [`second_tangent`](Self::second_tangent)
    /// (`Dual<f64>`).
    pub fn eval_folded<S: Scalar>(
        &self,
        head: &[S],
        first_bias: &[f64],
        scratch: &mut MlpScratch<S>,
        out: &mut [S],
        record: Option<&mut [f64]>,
    ) {
        let first = LayerInput {
            inputs: head.len(),
            bias: Some(first_bias),
        };
        self.eval_dispatch(head, first, scratch, out, record)
    }

    /// The Jacobian-vector product `dout = ∂MLP/∂x · dx` at the input of the
    /// [`eval_folded`](Self::eval_folded) call that wrote `record`, along the leading
    /// inputs `dx` (the folded ones are fixed):
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

    /// [`eval_folded`](Self::eval_folded) at `head` and the [`tangent`](Self::tangent)
    /// `dout` at the recorded point in one sweep over the weights: each layer multiplies
    /// both vectors at once.
    #[allow(clippy::too_many_arguments)]
    pub fn eval_and_tangent(
        &self,
        head: &[f64],
        first_bias: &[f64],
        out: &mut [f64],
        record: &[f64],
        dx: &[f64],
        dout: &mut [f64],
        scratch: &mut MlpScratch<Dual<f64>>,
    ) {
        let primal = Primal {
            head,
            first_bias,
            out,
        };
        self.sweep_dispatch(record, dx, dout, Some(primal), scratch)
    }

    /// The second-order tangent at the input `x + ẋ ε₂` of the `Dual<f64>`
    /// [`eval_folded`](Self::eval_folded) call that wrote `record`: along `dx + dẋ ε₂`,
    /// `dout + dȯut ε₂ = ∂MLP/∂x (x + ẋ ε₂) · (dx + dẋ ε₂)`. Per hidden layer, with the
    /// recorded `h` and `ḣ`: `a = W_j dh_j`, `ȧ = W_j dḣ_j`, `dh_{j+1} = (1 - h²) ⊙ a`,
    /// `dḣ_{j+1} = (1 - h²) ⊙ ȧ - 2 h ⊙ ḣ ⊙ a`. Two planes and no `tanh`, against the
    /// four planes of a nested dual-number pass.
    ///
    /// Returns `[dout, dȯut]` where the last layer left them in `scratch`: the caller
    /// reads them in place rather than through a copy.
    pub fn second_tangent<'s>(
        &self,
        record: &[f64],
        dx: [&[f64]; 2],
        scratch: &'s mut MlpScratch<Dual<f64>>,
    ) -> [&'s [f64]; 2] {
        let stride = scratch.stride;
        for (plane, d) in scratch.front.chunks_exact_mut(stride).zip(dx) {
            plane[..d.len()].copy_from_slice(d);
        }
        let inputs = dx[0].len();
        let simd = Simd::detect();
        simd.compiled(
            #[inline(always)]
            || self.second_with(simd, record, inputs, scratch),
        );
        let (dout, dout_dot) = scratch.back.split_at(stride);
        let n = self.output_dim();
        [&dout[..n], &dout_dot[..n]]
    }

    #[inline(always)]
    fn second_with(
        &self,
        simd: Simd,
        mut record: &[f64],
        inputs: usize,
        scratch: &mut MlpScratch<Dual<f64>>,
    ) {
        let planes = Planes {
            lanes: 2,
            stride: scratch.stride,
        };
        let MlpScratch { front, back, .. } = scratch;
        let first = LayerInput { inputs, bias: None };
        let last = self.layers.len() - 1;
        for (j, (layer, mut layer_input)) in self.layer_inputs(first).enumerate() {
            layer_input.bias = None;
            layer.apply(planes, front, back, layer_input, simd);
            if j == last {
                break;
            }
            let n = layer.padded_outputs;
            let (kept, rest) = record.split_at(2 * n);
            let (h, h_dot) = kept.split_at(n);
            let (a, a_dot) = back.split_at_mut(planes.stride);
            for (((a, a_dot), h), h_dot) in a[..n].iter_mut().zip(&mut a_dot[..n]).zip(h).zip(h_dot)
            {
                let slope = 1.0 - h * h;
                *a_dot = slope * *a_dot - 2.0 * h * h_dot * *a;
                *a *= slope;
            }
            record = rest;
            std::mem::swap(front, back);
        }
    }

    /// Runs [`eval_with`](Self::eval_with) on the best instruction set of this CPU.
    fn eval_dispatch<S: Scalar>(
        &self,
        input: &[S],
        first: LayerInput,
        scratch: &mut MlpScratch<S>,
        out: &mut [S],
        record: Option<&mut [f64]>,
    ) {
        let simd = Simd::detect();
        simd.compiled(
            #[inline(always)]
            || self.eval_with(simd, input, first, scratch, out, record),
        )
    }

    /// The layers in order, the first one reading as `first` says.
    fn layer_inputs<'a>(
        &'a self,
        first: LayerInput<'a>,
    ) -> impl Iterator<Item = (&'a Linear, LayerInput<'a>)> {
        let rest = self.layers[1..].iter().map(|l| (l, l.full_input()));
        std::iter::once((&self.layers[0], first)).chain(rest)
    }

    #[inline(always)]
    fn eval_with<S: Scalar>(
        &self,
        simd: Simd,
        input: &[S],
        first: LayerInput,
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
        let last = self.layers.len() - 1;
        for (j, (layer, layer_input)) in self.layer_inputs(first).enumerate() {
            layer.apply(planes, front, back, layer_input, simd);
            if j == last {
                break;
            }
            let n = layer.padded_outputs;
            activate::<S>(simd, planes, n, back);
            if let Some(rest) = record.take() {
                let (kept, rest) = rest.split_at_mut(planes.lanes * n);
                for (l, kept) in kept.chunks_exact_mut(n).enumerate() {
                    kept.copy_from_slice(&back[l * planes.stride..][..n]);
                }
                record = Some(rest);
            }
            std::mem::swap(front, back);
        }
        let (n, stride) = (out.len(), planes.stride);
        if planes.lanes > 4 {
            for (j, o) in out.iter_mut().enumerate() {
                *o = S::from_lanes(|l| back[l * stride + j]);
            }
            return;
        }
        // Up to four lanes (the policy's scalars), each plane is sliced once so that the
        // loop reads them without bounds checks: a quarter of the instructions.
        let lanes: [&[f64]; 4] = std::array::from_fn(|l| {
            if l < planes.lanes {
                &back[l * stride..][..n]
            } else {
                &[]
            }
        });
        for (j, o) in out.iter_mut().enumerate() {
            *o = S::from_lanes(|l| lanes[l][j]);
        }
    }

    /// Runs [`sweep_with`](Self::sweep_with) on the best instruction set of this CPU.
    fn sweep_dispatch(
        &self,
        record: &[f64],
        dx: &[f64],
        dout: &mut [f64],
        primal: Option<Primal>,
        scratch: &mut MlpScratch<Dual<f64>>,
    ) {
        let simd = Simd::detect();
        simd.compiled(
            #[inline(always)]
            || self.sweep_with(simd, record, dx, dout, primal, scratch),
        )
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
        primal: Option<Primal>,
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
        let first = LayerInput {
            inputs: dx.len(),
            bias: None,
        };
        let first = match &primal {
            Some(p) => {
                front[..p.head.len()].copy_from_slice(p.head);
                LayerInput {
                    bias: Some(p.first_bias),
                    ..first
                }
            }
            None => first,
        };
        let last = self.layers.len() - 1;
        let mut record = record;
        for (j, (layer, mut layer_input)) in self.layer_inputs(first).enumerate() {
            if !with_primal {
                layer_input.bias = None;
            }
            layer.apply(planes, front, back, layer_input, simd);
            if j == last {
                break;
            }
            let n = layer.padded_outputs;
            let (h, rest) = record.split_at(n);
            let (values, derivatives) = back.split_at_mut(tangent);
            for (d, h) in derivatives[..n].iter_mut().zip(h) {
                *d *= 1.0 - h * h;
            }
            if with_primal {
                for v in &mut values[..n] {
                    *v = tanh(simd, *v);
                }
            }
            record = rest;
            std::mem::swap(front, back);
        }
        dout.copy_from_slice(&back[tangent..tangent + dout.len()]);
        if let Some(primal) = primal {
            primal.out.copy_from_slice(&back[..primal.out.len()]);
        }
    }
}

/// The point [`Mlp::eval_and_tangent`] evaluates besides the tangent.
struct Primal<'a> {
    head: &'a [f64],
    first_bias: &'a [f64],
    out: &'a mut [f64],
}

/// `h ← tanh(h)` on the first `n` entries of the component planes `h`.
///
/// One and two lanes (`f64`, `Dual<f64>`) and four (`Dual<Dual<f64>>`) have their chain
/// rule written out plane by plane so the loops vectorise; more lanes go through
/// [`Scalar::tanh`] entry by entry.
#[inline(always)]
fn activate<S: Scalar>(simd: Simd, planes: Planes, n: usize, h: &mut [f64]) {
    let stride = planes.stride;
    match planes.lanes {
        1 => {
            for v in &mut h[..n] {
                *v = tanh(simd, *v);
            }
        }
        // `tanh(a + b ε) = t + b t' ε`, `t = tanh a`, `t' = 1 - t²`.
        2 => {
            let (a, b) = h.split_at_mut(stride);
            for (a, b) in a[..n].iter_mut().zip(&mut b[..n]) {
                let t = tanh(simd, *a);
                *a = t;
                *b *= 1.0 - t * t;
            }
        }
        // `tanh((a + b ε₁) + (c + d ε₁) ε₂) = t + b t' ε₁ + (c t' + (d t' + b c t'') ε₁) ε₂`,
        // `t'' = -2 t t'`.
        4 => {
            let (ab, cd) = h.split_at_mut(2 * stride);
            let (a, b) = ab.split_at_mut(stride);
            let (c, d) = cd.split_at_mut(stride);
            let planes = a[..n].iter_mut().zip(&mut b[..n]);
            for ((a, b), (c, d)) in planes.zip(c[..n].iter_mut().zip(&mut d[..n])) {
                let t = tanh(simd, *a);
                let first = 1.0 - t * t;
                let second = -2.0 * t * first;
                *a = t;
                *d = *d * first + *b * *c * second;
                *b *= first;
                *c *= first;
            }
        }
        _ => {
            for j in 0..n {
                let t = S::from_lanes(|l| h[l * stride + j]).tanh();
                for l in 0..planes.lanes {
                    h[l * stride + j] = t.lane(l);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    use super::*;
    #[cfg(target_arch = "x86_64")]
    use crate::math::simd::{has_avx2_fma, has_avx512f};

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

    /// The kernels this CPU can run, best last.
    fn kernels() -> Vec<Simd> {
        let mut kernels = vec![Simd::Portable];
        #[cfg(target_arch = "x86_64")]
        if has_avx2_fma() {
            kernels.push(Simd::Avx2Fma);
            if has_avx512f() {
                kernels.push(Simd::Avx512);
            }
        }
        kernels
    }

    /// Every kernel of this CPU, and the one `eval` picks, against the portable one, in
    /// `S`.
    fn check_kernels<S: Scalar>(mlp: &Mlp) {
        let x = inputs::<S>(mlp.input_dim(), 0.1);
        let mut scratch = MlpScratch::new(mlp);
        let zero = S::constant(0.0);
        let (mut fast, mut portable) = (vec![zero; mlp.output_dim()], vec![zero; mlp.output_dim()]);
        let first = mlp.layers[0].full_input();
        mlp.eval_with(Simd::Portable, &x, first, &mut scratch, &mut portable, None);
        mlp.eval(&x, &mut scratch, &mut fast);
        assert_close(&fast, &portable, 1e-12);
        for simd in kernels() {
            simd.compiled(
                #[inline(always)]
                || mlp.eval_with(simd, &x, first, &mut scratch, &mut fast, None),
            );
            assert_close(&fast, &portable, 1e-12);
        }
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

    fn check_activation<S: Scalar>() {
        let (n, stride) = (13, 16);
        let values = inputs::<S>(n, 0.4);
        let mut planes = vec![0.0; S::LANES * stride];
        for (j, v) in values.iter().enumerate() {
            for l in 0..S::LANES {
                planes[l * stride + j] = 3.0 * v.lane(l);
            }
        }
        let layout = Planes {
            lanes: S::LANES,
            stride,
        };
        activate::<S>(Simd::detect(), layout, n, &mut planes);
        let got: Vec<S> = (0..n)
            .map(|j| S::from_lanes(|l| planes[l * stride + j]))
            .collect();
        let expected: Vec<S> = values.iter().map(|v| (*v * 3.0).tanh()).collect();
        assert_close(&got, &expected, 1e-14);
    }

    #[test]
    fn plane_activations_match_the_scalar_tanh() {
        check_activation::<f64>();
        check_activation::<Dual<f64>>();
        check_activation::<Dual2>();
        check_activation::<Dual<Dual2>>();
    }

    /// Folded context, recorded activations, tangents and the fused sweep against plain
    /// evaluations in `f64` and dual numbers.
    #[test]
    fn recorded_tangents_match_dual_numbers() {
        let mlp = random_mlp(&[6, 37, 70, 13], 7);
        let (n, m, head) = (mlp.input_dim(), mlp.output_dim(), 4);
        let (x, dx, other) = (
            inputs::<f64>(n, 0.1),
            inputs::<f64>(head, 2.0),
            inputs::<f64>(head, 4.0),
        );
        let mut bias = vec![0.0; mlp.folded_bias_len()];
        mlp.fold_trailing_inputs(&x[head..], &mut bias);
        let mut record = vec![0.0; mlp.record_len()];
        let mut scratch = MlpScratch::new(&mlp);
        let mut out = vec![0.0; m];
        mlp.eval_folded(&x[..head], &bias, &mut scratch, &mut out, Some(&mut record));

        let duals: Vec<Dual<f64>> = (0..n)
            .map(|i| Dual::new(x[i], dx.get(i).copied().unwrap_or(0.0)))
            .collect();
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
            &bias,
            &mut other_out,
            &record,
            &dx,
            &mut fused_tangent,
            &mut pair_scratch,
        );
        let full: Vec<f64> = other.iter().chain(&x[head..]).copied().collect();
        let mut other_expected = vec![0.0; m];
        mlp.eval(&full, &mut scratch, &mut other_expected);
        assert_close(&other_out, &other_expected, 1e-12);
        assert_close(&fused_tangent, &expected_tangent, 1e-12);
    }

    /// The second-order tangent from a `Dual<f64>` record against a nested dual-number
    /// evaluation at `(x + ẋ ε₂) + (dx + dẋ ε₂) ε₁` (the folded inputs fixed).
    #[test]
    fn second_tangents_match_nested_dual_numbers() {
        let mlp = random_mlp(&[6, 37, 70, 13], 9);
        let (n, m, head) = (mlp.input_dim(), mlp.output_dim(), 4);
        let x = inputs::<Dual<f64>>(n, 0.3);
        let (dx, dx_dot) = (inputs::<f64>(head, 1.1), inputs::<f64>(head, 2.7));
        let context: Vec<f64> = x[head..].iter().map(|v| v.re).collect();
        let point: Vec<Dual<f64>> = x[..head].to_vec();
        let mut bias = vec![0.0; mlp.folded_bias_len()];
        mlp.fold_trailing_inputs(&context, &mut bias);
        let mut record = vec![0.0; 2 * mlp.record_len()];
        let mut scratch = MlpScratch::new(&mlp);
        let mut out = vec![Dual::new(0.0, 0.0); m];
        mlp.eval_folded(&point, &bias, &mut scratch, &mut out, Some(&mut record));
        let [dout, dout_dot] = mlp.second_tangent(&record, [&dx, &dx_dot], &mut scratch);

        let nested: Vec<Dual2> = (0..n)
            .map(|i| match i < head {
                true => Dual::new(x[i], Dual::new(dx[i], dx_dot[i])),
                false => Dual::new(Dual::new(context[i - head], 0.0), Dual::new(0.0, 0.0)),
            })
            .collect();
        let mut expected = vec![Dual::new(Dual::new(0.0, 0.0), Dual::new(0.0, 0.0)); m];
        mlp.eval(&nested, &mut MlpScratch::new(&mlp), &mut expected);
        let tangent: Vec<f64> = expected.iter().map(|e| e.du.re).collect();
        let tangent_dot: Vec<f64> = expected.iter().map(|e| e.du.du).collect();
        assert_close(dout, &tangent, 1e-12);
        assert_close(dout_dot, &tangent_dot, 1e-12);
        assert!(dout_dot.iter().any(|v| v.abs() > 1e-3));
    }
}
