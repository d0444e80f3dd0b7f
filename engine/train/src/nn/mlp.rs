//! The dense `tanh` network of `ciflow_engine::nn::mlp` in tch, batched over rows, with
//! the same parameter names.

use tch::Tensor;
use tch::nn::{self, Module};

/// `tanh` MLP with a linear last layer, named `{path}.{j}.weight|bias` like the engine.
#[derive(Debug)]
pub struct Mlp {
    layers: Vec<nn::Linear>,
}

impl Mlp {
    /// `zero_last`: initialise the last layer to zero (the coupling starts as the identity).
    pub fn new(path: &nn::Path, sizes: &[usize], zero_last: bool) -> Self {
        let n = sizes.len() - 1;
        let layers = sizes
            .windows(2)
            .enumerate()
            .map(|(j, io)| {
                let config = if zero_last && j + 1 == n {
                    nn::LinearConfig {
                        ws_init: nn::Init::Const(0.0),
                        bs_init: Some(nn::Init::Const(0.0)),
                        bias: true,
                    }
                } else {
                    nn::LinearConfig::default()
                };
                nn::linear(path / j, io[0] as i64, io[1] as i64, config)
            })
            .collect();
        Self { layers }
    }

    pub fn forward(&self, x: &Tensor) -> Tensor {
        let (last, hidden) = self.layers.split_last().expect("an MLP has a layer");
        let h = hidden
            .iter()
            .fold(x.shallow_clone(), |h, l| l.forward(&h).tanh());
        last.forward(&h)
    }
}
