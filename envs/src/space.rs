//! Gymnasium `Box` spaces.

use serde::{Deserialize, Serialize};

/// Element type of a space, as numpy names it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Dtype {
    Float32,
    Float64,
}

/// A box `[low, high]` in `R^n` (Gymnasium's `spaces.Box` with a 1-D shape).
/// Unbounded sides are `±inf`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BoxSpace {
    pub low: Vec<f64>,
    pub high: Vec<f64>,
    pub dtype: Dtype,
}

impl BoxSpace {
    pub fn new(low: Vec<f64>, high: Vec<f64>, dtype: Dtype) -> Self {
        assert_eq!(low.len(), high.len(), "BoxSpace bounds differ in length");
        Self { low, high, dtype }
    }

    /// Number of elements, `n` in `R^n`.
    pub fn dim(&self) -> usize {
        self.low.len()
    }

    /// Whether `x` has the right length and lies inside the bounds.
    pub fn contains(&self, x: &[f64]) -> bool {
        x.len() == self.dim()
            && x.iter()
                .zip(self.low.iter().zip(&self.high))
                .all(|(v, (lo, hi))| v.is_finite() && *lo <= *v && *v <= *hi)
    }
}
