//! Multilayer perceptron `h_{j+1} = tanh(W_j h_j + b_j)`, linear last layer.
//!
//! `tanh` keeps the network smooth (the acceleration feed-forward differentiates it twice)
//! and its Jacobian bounded. Weights are stored transposed (`[in][out]`) so each input
//! adds a contiguous row to the output, a loop the compiler vectorises.

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
    outputs: usize,
    /// `Wᵀ`, row `i` holds the weights of input `i`.
    weight_t: Vec<f64>,
    bias: Vec<f64>,
}

impl Linear {
    #[inline(always)]
    fn apply<S: Scalar>(&self, x: &[S], out: &mut [S]) {
        for (o, b) in out.iter_mut().zip(&self.bias) {
            *o = S::constant(*b);
        }
        for (xi, row) in x.iter().zip(self.weight_t.chunks_exact(self.outputs)) {
            for (o, w) in out.iter_mut().zip(row) {
                *o += *xi * *w;
            }
        }
    }
}

#[derive(Clone, Debug)]
pub struct Mlp {
    sizes: Vec<usize>,
    layers: Vec<Linear>,
}

/// Hidden-activation buffers of an [`Mlp`] evaluation.
#[derive(Clone, Debug)]
pub struct MlpScratch<S> {
    front: Vec<S>,
    back: Vec<S>,
}

impl<S: Scalar> MlpScratch<S> {
    pub fn new(mlp: &Mlp) -> Self {
        let width = mlp.sizes.iter().copied().max().unwrap_or(0);
        Self {
            front: vec![S::constant(0.0); width],
            back: vec![S::constant(0.0); width],
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
            let mut weight_t = vec![0.0; inputs * outputs];
            for o in 0..outputs {
                for i in 0..inputs {
                    weight_t[i * outputs + o] = weight[o * inputs + i];
                }
            }
            layers.push(Linear { outputs, weight_t, bias });
        }
        Ok(Self { sizes: sizes.to_vec(), layers })
    }

    pub fn input_dim(&self) -> usize {
        self.sizes[0]
    }

    pub fn output_dim(&self) -> usize {
        self.sizes[self.sizes.len() - 1]
    }

    /// `out = MLP(input)`; allocation-free. On x86-64 CPUs with AVX2 the same code runs
    /// compiled for 4-wide vectors (detected once, at run time).
    pub fn eval<S: Scalar>(&self, input: &[S], scratch: &mut MlpScratch<S>, out: &mut [S]) {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: AVX2 support was just detected.
            return unsafe { self.eval_avx2(input, scratch, out) };
        }
        self.eval_portable(input, scratch, out)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn eval_avx2<S: Scalar>(&self, input: &[S], scratch: &mut MlpScratch<S>, out: &mut [S]) {
        self.eval_portable(input, scratch, out)
    }

    #[inline(always)]
    fn eval_portable<S: Scalar>(&self, input: &[S], scratch: &mut MlpScratch<S>, out: &mut [S]) {
        let (last, hidden) = self.layers.split_last().expect("an MLP has a layer");
        let MlpScratch { front, back } = scratch;
        let mut width = input.len();
        front[..width].copy_from_slice(input);
        for layer in hidden {
            let (x, h) = (&front[..width], &mut back[..layer.outputs]);
            layer.apply(x, h);
            for v in h.iter_mut() {
                *v = v.tanh();
            }
            width = layer.outputs;
            std::mem::swap(front, back);
        }
        last.apply(&front[..width], out);
    }
}
