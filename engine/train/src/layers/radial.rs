//! The radial contractions `P_c` of `ciflow_engine::flow::layers::radial` in tch, parameter for
//! parameter: per layer `P(y) = y − Σ_i (1 − s(q_i)) (y − o_i)`,
//! `s(q) = 1 − (α / K) / (1 + (q / w²)^m)`, `α = sigmoid(strength)`,
//! `w = radius · exp(width)`, with `log|det ∂P/∂y| = log det J`,
//! `J = (1 − Σ_i (1 − s_i)) I + 2 Σ_i s'(q_i) v_i v_iᵀ` (symmetric positive definite).

use ciflow_engine::flow::ContractionConfig;
use ciflow_engine::flow::checkpoint::names::{RADIAL, STRENGTH, WIDTH};
use tch::{Kind, Tensor, nn};

/// Initial `strength`: `α = sigmoid(4) ≈ 0.98` (`α / K` per centre), a contraction strong
/// enough that the obstacles bend the initial paths, which the likelihood then tunes.
const INITIAL_STRENGTH: f64 = 4.0;
/// Newton steps of the inverse, and the halvings each may take to decrease `‖P(y) − u‖`.
const INVERSE_STEPS: usize = 40;
const BACKTRACKS: usize = 8;

#[derive(Debug)]
pub struct Contractions {
    config: ContractionConfig,
    /// `(strength, width)` of each layer.
    layers: Vec<(Tensor, Tensor)>,
}

/// One layer's `β = α / K` and `w²`.
struct Profile {
    beta: Tensor,
    width_sq: Tensor,
    exponent: u32,
}

impl Profile {
    /// `(P(y), J)` for `y` `[B, d]` about `centres` `[B, K, d]`: `[B, d]` and `[B, d, d]`.
    fn layer(&self, y: &Tensor, centres: &Tensor) -> (Tensor, Tensor) {
        let v = y.unsqueeze(1) - centres;
        let x = v.square().sum_dim_intlist(2, true, Kind::Double) / &self.width_sq;
        let m = i64::from(self.exponent);
        let power_below = x.pow_tensor_scalar(m - 1);
        let denominator = &power_below * &x + 1.0;
        let pull = &self.beta / &denominator;
        let slope = power_below * (&self.beta * f64::from(self.exponent) / &self.width_sq)
            / denominator.square();
        let image = y - (&pull * &v).sum_dim_intlist(1, false, Kind::Double);
        let d = y.size()[1];
        let diagonal = pull.sum_dim_intlist(1, true, Kind::Double).neg() + 1.0;
        let identity = Tensor::eye(d, (Kind::Double, y.device()));
        let outer = Tensor::einsum("bki,bkj->bij", &[&v * (slope * 2.0), v], None::<i64>);
        (image, diagonal * identity + outer)
    }
}

impl Contractions {
    pub fn new(path: &nn::Path, config: &ContractionConfig) -> Self {
        let layers = (0..config.layers)
            .map(|l| {
                let p = path / RADIAL / l;
                (
                    p.var(STRENGTH, &[1], nn::Init::Const(INITIAL_STRENGTH)),
                    p.var(WIDTH, &[1], nn::Init::Const(0.0)),
                )
            })
            .collect();
        Self {
            config: *config,
            layers,
        }
    }

    /// The raw context's centres as `[B, count, d]`.
    pub fn centres(&self, context: &Tensor) -> Tensor {
        let set = self.config.centres;
        context
            .narrow(1, set.start as i64, (set.count * set.size) as i64)
            .reshape([-1, set.count as i64, set.size as i64])
    }

    /// The layers' profiles, in order of application.
    fn profiles(&self) -> impl DoubleEndedIterator<Item = Profile> + '_ {
        let count = self.config.centres.count as f64;
        self.layers.iter().map(move |(strength, width)| {
            let w = width.exp() * self.config.radius;
            Profile {
                beta: strength.sigmoid() / count,
                width_sq: w.square(),
                exponent: self.config.exponent,
            }
        })
    }

    /// `(P_c(y), log|det ∂P_c/∂y|)` for `y` `[B, d]` and centres `[B, count, d]`.
    pub fn apply(&self, y: &Tensor, centres: &Tensor) -> (Tensor, Tensor) {
        let mut u = y.shallow_clone();
        let mut log_det = Tensor::zeros([y.size()[0]], (Kind::Double, y.device()));
        for profile in self.profiles() {
            let (image, jacobian) = profile.layer(&u, centres);
            log_det += Tensor::linalg_slogdet(&jacobian).1;
            u = image;
        }
        (u, log_det)
    }

    /// `P_c⁻¹(u)`: per layer, Newton's method on `P(y) − u` with backtracking, without
    /// gradient, then one Newton step with it, which carries the exact first derivatives
    /// through the root.
    pub fn invert(&self, u: &Tensor, centres: &Tensor) -> Tensor {
        let mut target = u.shallow_clone();
        for profile in self.profiles().rev() {
            let residual = |y: &Tensor| {
                let (image, jacobian) = profile.layer(y, centres);
                (image - &target, jacobian)
            };
            let newton = |y: &Tensor| {
                let (r, jacobian) = residual(y);
                Tensor::linalg_solve(&jacobian, &r.unsqueeze(2), true).squeeze_dim(2)
            };
            let squared_norm = |r: &Tensor| r.square().sum_dim_intlist(1, true, Kind::Double);
            let root = tch::no_grad(|| {
                // A copy: the steps below update `y` in place, and a detached tensor
                // shares its storage with `target`.
                let mut y = target.detach().copy();
                for _ in 0..INVERSE_STEPS {
                    let step = newton(&y);
                    let norm = squared_norm(&residual(&y).0);
                    let mut length = Tensor::ones_like(&norm);
                    for _ in 0..BACKTRACKS {
                        let trial = &y - &length * &step;
                        let worse = squared_norm(&residual(&trial).0).ge_tensor(&norm);
                        length = (&length * 0.5).where_self(&worse, &length);
                    }
                    y -= length * step;
                }
                y
            });
            target = &root - newton(&root);
        }
        target
    }
}
