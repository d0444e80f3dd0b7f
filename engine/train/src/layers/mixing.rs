//! The LU mixing of `ciflow_engine::flow::layers::mixing` in tch, parameter for
//! parameter.

use ciflow_engine::flow::checkpoint::names::{BIAS, LOG_DIAG, LOWER, UPPER};
use tch::nn;
use tch::{Kind, Tensor};

/// LU mixing `y = L U x + b`.
#[derive(Debug)]
pub struct LuMixing {
    lower: Tensor,
    upper: Tensor,
    log_diag: Tensor,
    bias: Tensor,
}

impl LuMixing {
    pub fn new(path: &nn::Path, d: usize) -> Self {
        let d = d as i64;
        let small = nn::Init::Randn {
            mean: 0.0,
            stdev: 0.1,
        };
        Self {
            lower: path.var(LOWER, &[d, d], small),
            upper: path.var(UPPER, &[d, d], small),
            log_diag: path.var(LOG_DIAG, &[d], nn::Init::Const(0.0)),
            bias: path.var(BIAS, &[d], nn::Init::Const(0.0)),
        }
    }

    fn matrix(&self) -> Tensor {
        let d = self.log_diag.size()[0];
        let eye = Tensor::eye(d, (self.lower.kind(), self.lower.device()));
        let l = self.lower.tril(-1) + eye;
        let u = self.upper.triu(1) + self.log_diag.exp().diag_embed(0, -2, -1);
        l.matmul(&u)
    }

    /// Returns `(y, log|det|)`, the log-determinant a scalar tensor.
    pub fn forward(&self, x: &Tensor) -> (Tensor, Tensor) {
        (
            x.matmul(&self.matrix().tr()) + &self.bias,
            self.log_diag.sum(Kind::Double),
        )
    }

    pub fn inverse(&self, y: &Tensor) -> (Tensor, Tensor) {
        let inv = self.matrix().inverse();
        (
            (y - &self.bias).matmul(&inv.tr()),
            -self.log_diag.sum(Kind::Double),
        )
    }
}
