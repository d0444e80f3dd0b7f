//! Gymnasium `Box` spaces.

use serde::{Deserialize, Serialize};

use crate::error::EnvError;

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

    /// Refuses `x` (named `what`) unless it has the space's dimension.
    pub fn check_dim(&self, what: &'static str, x: &[f64]) -> Result<(), EnvError> {
        if x.len() == self.dim() {
            Ok(())
        } else {
            Err(EnvError::WrongDimension {
                what,
                expected: self.dim(),
                got: x.len(),
            })
        }
    }

    /// Like [`BoxSpace::contains`], but says what is wrong with `x` (named `what`).
    pub fn check(&self, what: &'static str, x: &[f64]) -> Result<(), EnvError> {
        self.check_dim(what, x)?;
        if x.iter().any(|v| !v.is_finite()) {
            return Err(EnvError::NotFinite { what });
        }
        match (0..x.len()).find(|&i| x[i] < self.low[i] || x[i] > self.high[i]) {
            Some(i) => Err(EnvError::OutOfBounds {
                what,
                detail: format!(
                    "element {i} = {} is not in [{}, {}]",
                    x[i], self.low[i], self.high[i]
                ),
            }),
            None => Ok(()),
        }
    }

    /// The nearest point of the box to `x` (same length as the space).
    pub fn clip(&self, x: &[f64]) -> Vec<f64> {
        x.iter()
            .zip(self.low.iter().zip(&self.high))
            .map(|(v, (lo, hi))| v.clamp(*lo, *hi))
            .collect()
    }
}
