//! The radial contractions `P_c` of `ciflow_engine::flow::radial` in tch, parameter for
//! parameter: `P(y) = o + s(q)(y − o)`, `s(q) = 1 − α / (1 + (q / w²)^m)`,
//! `α = sigmoid(strength)`, `w = radius · exp(width)`.

use ciflow_engine::flow::ContractionConfig;
use tch::{Kind, Tensor, nn};

/// Initial `strength`: `α = sigmoid(2) ≈ 0.88`, a contraction strong enough that the
/// obstacles bend the initial paths, which the likelihood then tunes.
const INITIAL_STRENGTH: f64 = 2.0;
/// Safeguarded Newton steps of the inverse (each halves the bracket at worst).
const INVERSE_STEPS: usize = 80;

#[derive(Debug)]
pub struct Contractions {
    config: ContractionConfig,
    /// `(strength, width)` of each layer.
    layers: Vec<(Tensor, Tensor)>,
}

/// `s`, `k' = s + 2q s'(q)` of one profile at `q` (`[B, 1]` each).
fn slopes(q: &Tensor, alpha: &Tensor, width_sq: &Tensor, exponent: u32) -> (Tensor, Tensor) {
    let t = (q / width_sq).pow_tensor_scalar(i64::from(exponent));
    let denominator = &t + 1.0;
    let scale = 1.0 - alpha / &denominator;
    let m = f64::from(exponent);
    let radial = 1.0 - alpha * (1.0 - &t * (2.0 * m - 1.0)) / denominator.square();
    (scale, radial)
}

impl Contractions {
    pub fn new(path: &nn::Path, config: &ContractionConfig) -> Self {
        let layers = (0..config.layers)
            .map(|l| {
                let p = path / "contraction" / l;
                (
                    p.var("strength", &[1], nn::Init::Const(INITIAL_STRENGTH)),
                    p.var("width", &[1], nn::Init::Const(0.0)),
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

    /// `(α, w²)` of each layer, in order of application.
    fn profiles(&self) -> impl DoubleEndedIterator<Item = (Tensor, Tensor)> + '_ {
        self.layers.iter().map(|(strength, width)| {
            let w = width.exp() * self.config.radius;
            (strength.sigmoid(), w.square())
        })
    }

    /// `(P_c(y), log|det ∂P_c/∂y|)` for `y` `[B, d]` and centres `[B, count, d]`.
    pub fn apply(&self, y: &Tensor, centres: &Tensor) -> (Tensor, Tensor) {
        let d = y.size()[1] as f64;
        let mut u = y.shallow_clone();
        let mut log_det = Tensor::zeros([y.size()[0]], (Kind::Double, y.device()));
        for (alpha, width_sq) in self.profiles() {
            for j in 0..self.config.centres.count as i64 {
                let o = centres.select(1, j);
                let v = &u - &o;
                let q = v.square().sum_dim_intlist(1, true, Kind::Double);
                let (scale, radial) = slopes(&q, &alpha, &width_sq, self.config.exponent);
                log_det += (radial.log() + scale.log() * (d - 1.0)).squeeze_dim(1);
                u = o + scale * v;
            }
        }
        (u, log_det)
    }

    /// `P_c⁻¹(u)`: per contraction, `q` solving `q s(q)² = ‖u − o‖²` by safeguarded
    /// Newton in its bracket `[ρ², ρ² / (1 − α)²]` without gradient, then one Newton step
    /// with it, which carries the exact first derivatives through the root.
    pub fn invert(&self, u: &Tensor, centres: &Tensor) -> Tensor {
        let mut y = u.shallow_clone();
        let exponent = self.config.exponent;
        for (alpha, width_sq) in self.profiles().rev() {
            for j in (0..self.config.centres.count as i64).rev() {
                let o = centres.select(1, j);
                let v = &y - &o;
                let rho_sq = v.square().sum_dim_intlist(1, true, Kind::Double);
                let residual = |q: &Tensor| {
                    let (scale, radial) = slopes(q, &alpha, &width_sq, exponent);
                    (q * scale.square() - &rho_sq, &scale * radial)
                };
                let root = tch::no_grad(|| {
                    let mut low = rho_sq.detach();
                    let mut high = &low / (alpha.neg() + 1.0).square();
                    let mut q = low.shallow_clone();
                    for _ in 0..INVERSE_STEPS {
                        let (h, slope) = residual(&q);
                        let above = h.ge(0.0);
                        low = low.where_self(&above, &q);
                        high = q.where_self(&above, &high);
                        let newton = &q - h / slope;
                        let inside = newton.gt_tensor(&low).logical_and(&newton.lt_tensor(&high));
                        q = newton.where_self(&inside, &((&low + &high) * 0.5));
                    }
                    q
                });
                let (h, slope) = residual(&root);
                let q = &root - h / slope;
                let (scale, _) = slopes(&q, &alpha, &width_sq, exponent);
                y = o + v / scale;
            }
        }
        y
    }
}
