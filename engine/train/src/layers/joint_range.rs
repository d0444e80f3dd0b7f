//! The tch twin of `ciflow_engine::flow::layers::joint_range`: `y = m + h ⊙ tanh(u)` onto
//! a robot's position limits, last in `f`. It has no parameters; the trainer needs it for
//! the log-determinant of every demonstrated state and the inverse of the targets.

use ciflow_engine::flow::JointRange;
use ciflow_engine::flow::layers::joint_range::EDGE;
use tch::{Kind, Tensor};

use crate::nn::row;

#[derive(Debug)]
pub struct JointRangeMap {
    centre: Tensor,
    half_width: Tensor,
    log_half_width: Tensor,
}

impl JointRangeMap {
    pub fn new(range: &JointRange) -> Self {
        let (centre, half): (Vec<f64>, Vec<f64>) = range
            .position_min
            .iter()
            .zip(&range.position_max)
            .map(|(lo, hi)| (0.5 * (hi + lo), 0.5 * (hi - lo)))
            .unzip();
        let half_width = row(&half);
        Self {
            centre: row(&centre),
            log_half_width: half_width.log().sum(Kind::Double),
            half_width,
        }
    }

    /// `(R(u), log|det ∂R/∂u|)` per row `[B, d]`.
    pub fn apply(&self, u: &Tensor) -> (Tensor, Tensor) {
        // ln(1 − tanh² u) = 2 ln 2 − 2u − 2 softplus(−2u), finite for every u.
        let log_sech2 = (u * -2.0).softplus() * -2.0 - u * 2.0 + 2.0 * std::f64::consts::LN_2;
        let log_det = log_sech2.sum_dim_intlist(1, false, Kind::Double) + &self.log_half_width;
        (u.tanh() * &self.half_width + &self.centre, log_det)
    }

    /// `∂R/∂u = h (1 − t²)` at `y = R(u)` per row and joint: what carries a step in the
    /// network's coordinates to one in the observation's.
    pub fn slope(&self, y: &Tensor) -> Tensor {
        let t = ((y - &self.centre) / &self.half_width).clamp(-1.0 + EDGE, 1.0 - EDGE);
        (&t * &t * -1.0 + 1.0) * &self.half_width
    }

    /// `(R⁻¹(y), log|det ∂R⁻¹/∂y|)` per row, states on or beyond a limit read just inside.
    pub fn invert(&self, y: &Tensor) -> (Tensor, Tensor) {
        let t = ((y - &self.centre) / &self.half_width).clamp(-1.0 + EDGE, 1.0 - EDGE);
        let log_one_minus_t2 = (&t + 1.0).log() + (&t * -1.0 + 1.0).log();
        let log_det =
            -(log_one_minus_t2.sum_dim_intlist(1, false, Kind::Double) + &self.log_half_width);
        (t.atanh(), log_det)
    }
}

#[cfg(test)]
mod tests {
    use super::JointRangeMap;
    use ciflow_engine::flow::JointRange;
    use tch::{Kind, Tensor};

    #[test]
    fn slope_is_the_derivative_of_the_map_and_invert_undoes_it() {
        let map = JointRangeMap::new(&JointRange {
            position_min: vec![-2.0, 0.5],
            position_max: vec![1.0, 3.5],
            speed_max: vec![1.0; 2],
            acceleration_max: vec![1.0; 2],
        });
        let y = Tensor::from_slice(&[-1.9, 0.6, 0.0, 2.0, 0.9, 3.4])
            .to_kind(Kind::Double)
            .reshape([3, 2]);
        let (u, inverse_log_det) = map.invert(&y);
        let (back, log_det) = map.apply(&u);
        assert!(f64::try_from((&back - &y).abs().max()).unwrap() < 1e-12);
        assert!(f64::try_from((&log_det + &inverse_log_det).abs().max()).unwrap() < 1e-9);
        let h = 1e-6;
        let difference = (map.apply(&(&u + h)).0 - map.apply(&(&u - h)).0) / (2.0 * h);
        let error = (map.slope(&y) - difference).abs().max();
        assert!(f64::try_from(error).unwrap() < 1e-7);
    }
}
