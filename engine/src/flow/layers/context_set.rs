//! Unordered sets in the context (e.g. obstacle centres), summarised by a learned encoder
//! that ignores the elements' order and moves continuously with each of them.
//!
//! A context whose entries `e₁, …, e_n ∈ ℝˢ` (at consecutive indices) form a set describes
//! the same task under every permutation of the elements. The conditioners see, instead
//! of the raw context, the *conditioning vector*
//!
//! `ĉ = [ã, φ̄₁, …, φ̄_K]`, `φ̄_k = (1/n_k) Σ_j φ_k([ẽ_j, ã])`,
//!
//! where `ã` are the normalised context entries outside every set (in their order), `ẽ_j`
//! the normalised elements of set `k` and `φ_k` an MLP (`s + |ã|` inputs, tanh hidden
//! layers, a linear output of width `W`): mean pooling, as in DeepSets (Zaheer et al.,
//! 2017). Each element is seen together with the rest of the context (for obstacles: each
//! centre with the target), so `φ` can encode relative positions.
//!
//! Two properties follow from the construction, for any weights:
//! - **invariance**: `ĉ` is the same for every order of a set's elements, exactly (the
//!   sum is evaluated in the given order, so only floating-point rounding can differ);
//! - **continuity**: `ĉ` is as smooth as `φ`, with `‖∂ĉ/∂e_j‖ ≤ Lip(φ)/n` — no jump
//!   where two elements' coordinates cross, unlike sorting the elements into slots.
//!
//! The normalisation of the elements is shared by all of a set's slots (its statistics
//! pool every element), so it too is invariant. Since `f(·, c)` is a bijection for every
//! conditioning vector, stability is untouched.

use serde::{Deserialize, Serialize};

use crate::flow::checkpoint::names::{self, ENCODER, LOCAL, SETS};
use crate::flow::checkpoint::weights::Weights;
use crate::flow::error::FlowResult;
use crate::nn::mlp::{Mlp, MlpScratch, mlp_parameter_shapes};

/// `count` consecutive elements of `size` entries each, from context index `start`, that
/// form an unordered set.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct ContextSet {
    pub start: usize,
    pub count: usize,
    pub size: usize,
}

impl std::fmt::Display for ContextSet {
    /// "5 points of 3 at context entries 0..15".
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} points of {} at context entries {}..{}",
            self.count,
            self.size,
            self.start,
            self.end()
        )
    }
}

impl ContextSet {
    /// One past the set's last context index.
    pub fn end(&self) -> usize {
        self.start + self.count * self.size
    }

    /// Whether context index `i` belongs to the set.
    pub fn contains(&self, i: usize) -> bool {
        (self.start..self.end()).contains(&i)
    }
}

/// Architecture of every set's encoder `φ`.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct SetEncoderConfig {
    /// Hidden widths of `φ`.
    pub hidden: Vec<usize>,
    /// `W`, the width of each pooled summary.
    pub width: usize,
    /// Every coupling's local element network `ψ` ([`crate::flow::layers::conditioner`]); none when
    /// absent.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub local: Option<LocalConfig>,
}

/// The default: `φ` as wide as the default conditioners (64-64) with a summary of 32
/// features, and no local features. Measured on obstacle avoidance (3 obstacles, 1000
/// demonstrations, 2 epochs, no radial contractions): local features of 16 from a
/// hidden layer of 32 reached the goal in 63% of 100 new contexts against 71% without,
/// and cost 2.5x the policy action (33 µs against 13 µs).
impl Default for SetEncoderConfig {
    fn default() -> Self {
        Self {
            hidden: vec![64, 64],
            width: 32,
            local: None,
        }
    }
}

/// Architecture of the couplings' local element networks `ψ` ([`crate::flow::layers::conditioner`]).
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct LocalConfig {
    /// Hidden widths of `ψ`.
    pub hidden: Vec<usize>,
    /// `W_ψ`, the width of each pooled local feature.
    pub width: usize,
}

/// Layer sizes of a coupling's `ψ` for `set`: `[kept + s + |ĉ|, hidden.., W_ψ]`.
pub fn local_sizes(
    set: &ContextSet,
    kept: usize,
    conditioning_dim: usize,
    config: &LocalConfig,
) -> Vec<usize> {
    let mut sizes = vec![kept + set.size + conditioning_dim];
    sizes.extend(&config.hidden);
    sizes.push(config.width);
    sizes
}

/// The parameter prefix of set `k`'s `ψ` in the coupling under `coupling_prefix`.
pub fn local_prefix(coupling_prefix: &str, k: usize) -> String {
    names::name(&[&coupling_prefix, &LOCAL, &k])
}

/// The context indices outside every set, in order: `ã`'s entries.
pub fn rest_indices(sets: &[ContextSet], context_dim: usize) -> Vec<usize> {
    (0..context_dim)
        .filter(|&i| !sets.iter().any(|s| s.contains(i)))
        .collect()
}

/// Layer sizes of the encoder of `set`: `[s + |ã|, hidden.., W]`.
pub fn encoder_sizes(set: &ContextSet, rest: usize, config: &SetEncoderConfig) -> Vec<usize> {
    let mut sizes = vec![set.size + rest];
    sizes.extend(&config.hidden);
    sizes.push(config.width);
    sizes
}

/// The parameter prefix of set `k`'s encoder, as the trainer names it.
pub fn encoder_prefix(k: usize) -> String {
    names::name(&[&SETS, &k, &ENCODER])
}

/// Names and shapes of every set encoder's parameters.
pub fn encoder_parameter_shapes(
    sets: &[ContextSet],
    context_dim: usize,
    config: &SetEncoderConfig,
) -> Vec<(String, Vec<usize>)> {
    let rest = rest_indices(sets, context_dim).len();
    sets.iter()
        .enumerate()
        .flat_map(|(k, set)| {
            mlp_parameter_shapes(&encoder_prefix(k), &encoder_sizes(set, rest, config))
        })
        .collect()
}

/// Maps normalised contexts to conditioning vectors `ĉ`.
#[derive(Clone, Debug)]
pub struct ContextEncoder {
    sets: Vec<(ContextSet, Mlp)>,
    rest: Vec<usize>,
    width: usize,
}

/// Buffers of [`ContextEncoder::encode`].
#[derive(Clone, Debug)]
pub struct EncoderScratch {
    input: Vec<f64>,
    output: Vec<f64>,
    mlp: Vec<MlpScratch<f64>>,
}

impl ContextEncoder {
    /// The identity on contexts without sets (`ĉ = c̃`).
    pub fn from_weights(
        sets: &[ContextSet],
        context_dim: usize,
        config: Option<&SetEncoderConfig>,
        weights: &mut Weights,
    ) -> FlowResult<Self> {
        let rest = rest_indices(sets, context_dim);
        let (sets, width) = match config {
            Some(config) => {
                let encoders = sets
                    .iter()
                    .enumerate()
                    .map(|(k, set)| {
                        let sizes = encoder_sizes(set, rest.len(), config);
                        Ok((
                            *set,
                            Mlp::from_weights(weights, &encoder_prefix(k), &sizes)?,
                        ))
                    })
                    .collect::<FlowResult<Vec<_>>>()?;
                (encoders, config.width)
            }
            None => (Vec::new(), 0),
        };
        Ok(Self { sets, rest, width })
    }

    /// `|ĉ|`.
    pub fn output_dim(&self) -> usize {
        self.rest.len() + self.sets.len() * self.width
    }

    pub fn scratch(&self) -> EncoderScratch {
        let input = self.sets.iter().map(|(_, m)| m.input_dim()).max();
        EncoderScratch {
            input: vec![0.0; input.unwrap_or(0)],
            output: vec![0.0; self.width],
            mlp: self.sets.iter().map(|(_, m)| MlpScratch::new(m)).collect(),
        }
    }

    /// `encoded = ĉ` for the normalised context `normalised`.
    pub fn encode(&self, normalised: &[f64], scratch: &mut EncoderScratch, encoded: &mut [f64]) {
        let rest = self.rest.len();
        for (e, &i) in encoded.iter_mut().zip(&self.rest) {
            *e = normalised[i];
        }
        let summaries = encoded[rest..].chunks_exact_mut(self.width.max(1));
        for (((set, mlp), summary), mlp_scratch) in
            self.sets.iter().zip(summaries).zip(&mut scratch.mlp)
        {
            summary.fill(0.0);
            let input = &mut scratch.input[..set.size + rest];
            for (slot, &i) in input[set.size..].iter_mut().zip(&self.rest) {
                *slot = normalised[i];
            }
            for j in 0..set.count {
                let element = set.start + j * set.size;
                input[..set.size].copy_from_slice(&normalised[element..element + set.size]);
                mlp.eval(input, mlp_scratch, &mut scratch.output);
                for (s, o) in summary.iter_mut().zip(&scratch.output) {
                    *s += o;
                }
            }
            for s in summary.iter_mut() {
                *s /= set.count as f64;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    const OBSTACLES: ContextSet = ContextSet {
        start: 1,
        count: 3,
        size: 2,
    };

    #[test]
    fn a_set_reads_as_its_points_and_entries() {
        assert_eq!(
            OBSTACLES.to_string(),
            "3 points of 2 at context entries 1..7"
        );
    }

    #[test]
    fn the_rest_skips_every_set() {
        assert_eq!(rest_indices(&[OBSTACLES], 9), [0, 7, 8]);
        assert_eq!(rest_indices(&[], 3), [0, 1, 2]);
    }

    #[test]
    fn every_permutation_gives_the_same_conditioning_and_the_rest_passes_through() {
        let config = SetEncoderConfig {
            hidden: vec![8],
            width: 5,
            local: None,
        };
        let shapes = encoder_parameter_shapes(&[OBSTACLES], 8, &config);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        let mut weights = Weights::random(&shapes, 1.0, &mut rng);
        let encoder =
            ContextEncoder::from_weights(&[OBSTACLES], 8, Some(&config), &mut weights).unwrap();
        assert_eq!(encoder.output_dim(), 2 + 5);
        let elements = [[0.3, -1.0], [-0.2, 5.0], [0.1, 2.0]];
        let mut scratch = encoder.scratch();
        let mut first: Option<Vec<f64>> = None;
        for p in [
            [0, 1, 2],
            [0, 2, 1],
            [1, 0, 2],
            [1, 2, 0],
            [2, 0, 1],
            [2, 1, 0],
        ] {
            let mut context = vec![9.0];
            context.extend(p.iter().flat_map(|&j| elements[j]));
            context.push(7.0);
            let mut encoded = vec![0.0; 7];
            encoder.encode(&context, &mut scratch, &mut encoded);
            assert_eq!(encoded[..2], [9.0, 7.0]);
            match &first {
                None => first = Some(encoded),
                Some(first) => {
                    for (a, b) in first.iter().zip(&encoded) {
                        assert!(
                            (a - b).abs() < 1e-14,
                            "permutation {p:?}: {first:?} {encoded:?}"
                        );
                    }
                }
            }
        }
    }
}
