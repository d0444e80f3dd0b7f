//! Named parameter tensors, read from and written to safetensors files with the names the
//! trainer's `VarStore` uses, so `VarStore::save("weights.safetensors")` loads here.

use std::collections::BTreeMap;
use std::path::Path;

use rand::Rng;
use rand_distr::{Distribution, StandardNormal};
use safetensors::tensor::{Dtype, SafeTensors, TensorView};

use crate::flow::error::{FlowError, FlowResult};

/// A dense row-major tensor.
#[derive(Clone, Debug, PartialEq)]
pub struct Tensor {
    pub shape: Vec<usize>,
    pub data: Vec<f64>,
}

/// Parameters by name. Building a model [`take`](Weights::take)s every tensor it needs
/// and [`finish`](Weights::finish) rejects leftovers, so a checkpoint of a different
/// architecture is an error rather than a silently partial load.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Weights {
    tensors: BTreeMap<String, Tensor>,
}

impl Weights {
    pub fn insert(&mut self, name: impl Into<String>, tensor: Tensor) {
        self.tensors.insert(name.into(), tensor);
    }

    pub fn get(&self, name: &str) -> Option<&Tensor> {
        self.tensors.get(name)
    }

    pub fn names(&self) -> impl Iterator<Item = &str> {
        self.tensors.keys().map(String::as_str)
    }

    /// Random parameters `N(0, scale² / fan_in)` (fan-in: last dimension of matrices, 1
    /// for vectors) — the "untrained" models of the stability tests and benchmarks.
    pub fn random(shapes: &[(String, Vec<usize>)], scale: f64, rng: &mut impl Rng) -> Self {
        let mut weights = Self::default();
        for (name, shape) in shapes {
            let fan_in = if shape.len() == 2 { shape[1] } else { 1 };
            let std = scale / (fan_in as f64).sqrt();
            let n = shape.iter().product();
            let data = (0..n)
                .map(|_| std * Distribution::<f64>::sample(&StandardNormal, rng))
                .collect::<Vec<f64>>();
            weights.insert(
                name.clone(),
                Tensor {
                    shape: shape.clone(),
                    data,
                },
            );
        }
        weights
    }

    /// Parses a safetensors buffer; F64 and F32 tensors are accepted (F32 widened).
    pub fn from_safetensors(bytes: &[u8]) -> FlowResult<Self> {
        let file = SafeTensors::deserialize(bytes)?;
        let mut weights = Self::default();
        for (name, view) in file.tensors() {
            let raw = view.data();
            let data = match view.dtype() {
                Dtype::F64 => raw
                    .chunks_exact(8)
                    .map(|b| f64::from_le_bytes(b.try_into().expect("8-byte chunk")))
                    .collect(),
                Dtype::F32 => raw
                    .chunks_exact(4)
                    .map(|b| f32::from_le_bytes(b.try_into().expect("4-byte chunk")) as f64)
                    .collect(),
                other => {
                    return Err(FlowError::UnsupportedDtype {
                        name,
                        dtype: format!("{other:?}"),
                    });
                }
            };
            weights.insert(
                name,
                Tensor {
                    shape: view.shape().to_vec(),
                    data,
                },
            );
        }
        Ok(weights)
    }

    pub fn load(path: &Path) -> FlowResult<Self> {
        let bytes = std::fs::read(path).map_err(|source| FlowError::Io {
            path: path.to_owned(),
            source,
        })?;
        Self::from_safetensors(&bytes)
    }

    /// Writes every tensor as F64.
    pub fn save(&self, path: &Path) -> FlowResult<()> {
        let bytes: Vec<(&str, Vec<u8>, &[usize])> = self
            .tensors
            .iter()
            .map(|(name, t)| {
                let raw = t.data.iter().flat_map(|v| v.to_le_bytes()).collect();
                (name.as_str(), raw, t.shape.as_slice())
            })
            .collect();
        let views = bytes
            .iter()
            .map(|(name, raw, shape)| {
                Ok((*name, TensorView::new(Dtype::F64, shape.to_vec(), raw)?))
            })
            .collect::<FlowResult<Vec<_>>>()?;
        safetensors::serialize_to_file(views, None, path)?;
        Ok(())
    }

    /// Removes and returns the tensor `name`, checking its shape.
    pub fn take(&mut self, name: &str, shape: &[usize]) -> FlowResult<Vec<f64>> {
        let tensor = self
            .tensors
            .remove(name)
            .ok_or_else(|| FlowError::MissingTensor {
                name: name.to_owned(),
            })?;
        if tensor.shape != shape {
            return Err(FlowError::ShapeMismatch {
                name: name.to_owned(),
                expected: shape.to_vec(),
                found: tensor.shape,
            });
        }
        if tensor.data.iter().any(|v| !v.is_finite()) {
            return Err(FlowError::NonFinite {
                what: "checkpoint weight",
            });
        }
        Ok(tensor.data)
    }

    /// Fails if a tensor was not taken: the file holds a different architecture.
    pub fn finish(self) -> FlowResult<()> {
        match self.tensors.into_keys().next() {
            Some(name) => Err(FlowError::UnexpectedTensor { name }),
            None => Ok(()),
        }
    }
}
