//! The conditioner of a coupling layer: the coupling parameters `θ` as a function of the
//! kept coordinates `x_k` and the context.
//!
//! Without context sets it is one MLP, `θ = MLP([x_k, ĉ])`. Over a context with unordered
//! sets ([`crate::flow::layers::context_set`]) it also pools, per set, a *local* feature of every
//! element seen from the current point:
//!
//! `θ = MLP([x_k, p₁, …, p_K, ĉ])`, `p_k = (1/n_k) Σ_j ψ_k([x_k, ẽ_j, ĉ])`,
//!
//! with `ψ_k` an MLP (`|x_k| + s + |ĉ|` inputs, tanh hidden layers, a linear output of
//! width `W_ψ`) and `ẽ_j` the normalised elements of set `k`. The pooled feature depends on
//! where the point is relative to each element, so a coupling can deform the space near
//! an obstacle wherever the context puts it (a context-only summary `ĉ` would have to
//! synthesise that locality from a global code). Like `ĉ`, `p_k` is invariant to the
//! order of the elements and continuous in each of them, and `θ` still depends only on
//! `x_k`, so the coupling stays triangular and invertible for any weights.
//!
//! The context enters through first-layer biases folded once per context
//! ([`Conditioner::fold_context`]): one for the MLP and one per element for each `ψ_k`,
//! back to back, so evaluations read only the columns of `x_k` (and of `p`).

use crate::flow::checkpoint::names::{self, CONDITIONER};
use crate::flow::checkpoint::weights::Weights;
use crate::flow::error::FlowResult;
use crate::flow::layers::context_set::{ContextSet, LocalConfig, local_prefix, local_sizes};
use crate::nn::mlp::{Mlp, MlpScratch};
use crate::nn::scalar::{Dual, Scalar};

/// `θ(x_k, c)` of one coupling (see the module docs).
#[derive(Clone, Debug)]
pub struct Conditioner {
    mlp: Mlp,
    /// `ψ_k` of every set, with the set it pools over.
    local: Vec<(ContextSet, Mlp)>,
    kept: usize,
    /// `W_ψ`.
    local_width: usize,
}

/// Buffers of a conditioner evaluation in scalar type `S`.
#[derive(Clone, Debug)]
pub struct ConditionerScratch<S> {
    /// `[x_k, p]`, the MLP's leading inputs.
    input: Vec<S>,
    feature: Vec<S>,
    mlp: MlpScratch<S>,
    local: Vec<MlpScratch<S>>,
}

impl<S: Scalar> ConditionerScratch<S> {
    pub fn new(conditioner: &Conditioner) -> Self {
        Self {
            input: vec![S::constant(0.0); conditioner.leading_dim()],
            feature: vec![S::constant(0.0); conditioner.local_width],
            mlp: MlpScratch::new(&conditioner.mlp),
            local: conditioner.local_scratches(),
        }
    }
}

/// Buffers of [`Conditioner::tangent`], [`Conditioner::eval_and_tangent`] and
/// [`Conditioner::second_tangent`].
#[derive(Clone, Debug)]
pub struct ConditionerTangentScratch {
    primal: ConditionerScratch<f64>,
    /// The MLP's leading inputs along the tangent, and their time derivatives.
    input_tangent: [Vec<f64>; 2],
    /// One `ψ` output along the tangent, and its time derivative.
    feature_tangent: [Vec<f64>; 2],
    mlp: MlpScratch<Dual<f64>>,
    local: Vec<MlpScratch<Dual<f64>>>,
}

impl ConditionerTangentScratch {
    pub fn new(conditioner: &Conditioner) -> Self {
        Self {
            primal: ConditionerScratch::new(conditioner),
            input_tangent: std::array::from_fn(|_| vec![0.0; conditioner.leading_dim()]),
            feature_tangent: std::array::from_fn(|_| vec![0.0; conditioner.local_width]),
            mlp: MlpScratch::new(&conditioner.mlp),
            local: conditioner.local_scratches(),
        }
    }
}

impl Conditioner {
    /// The conditioner of coupling `{prefix}`: the MLP of layer sizes `sizes` under
    /// `{prefix}.conditioner`, and with `local` one `ψ_k` per set under `{prefix}.local.{k}`
    /// over conditioning vectors of `conditioning_dim` entries.
    pub fn from_weights(
        weights: &mut Weights,
        prefix: &str,
        sizes: &[usize],
        kept: usize,
        sets: &[ContextSet],
        local: Option<&LocalConfig>,
        conditioning_dim: usize,
    ) -> FlowResult<Self> {
        let mlp = Mlp::from_weights(weights, &names::name(&[&prefix, &CONDITIONER]), sizes)?;
        let (local, local_width) = match local {
            Some(config) => {
                let nets = sets
                    .iter()
                    .enumerate()
                    .map(|(k, set)| {
                        let sizes = local_sizes(set, kept, conditioning_dim, config);
                        Ok((
                            *set,
                            Mlp::from_weights(weights, &local_prefix(prefix, k), &sizes)?,
                        ))
                    })
                    .collect::<FlowResult<Vec<_>>>()?;
                (nets, config.width)
            }
            None => (Vec::new(), 0),
        };
        Ok(Self {
            mlp,
            local,
            kept,
            local_width,
        })
    }

    /// One activation buffer per `ψ_k`.
    fn local_scratches<S: Scalar>(&self) -> Vec<MlpScratch<S>> {
        self.local.iter().map(|(_, m)| MlpScratch::new(m)).collect()
    }

    /// `|x_k| + K W_ψ`, the inputs that vary from point to point.
    fn leading_dim(&self) -> usize {
        self.kept + self.local.len() * self.local_width
    }

    pub fn output_dim(&self) -> usize {
        self.mlp.output_dim()
    }

    /// `Σ_k n_k · len(ψ_k)`: a per-element length summed over every element of every set.
    fn per_element(&self, len: impl Fn(&Mlp) -> usize) -> usize {
        self.local.iter().map(|(set, m)| set.count * len(m)).sum()
    }

    /// Length of the context bias [`fold_context`](Self::fold_context) writes.
    pub fn context_bias_len(&self) -> usize {
        self.mlp.folded_bias_len() + self.per_element(Mlp::folded_bias_len)
    }

    /// Length of the record of a recorded evaluation, per component of its scalar type.
    pub fn record_len(&self) -> usize {
        self.mlp.record_len() + self.per_element(Mlp::record_len)
    }

    /// The first-layer biases with the context folded in: the MLP's with `ĉ` (`encoded`),
    /// each `ψ_k`'s once per element with `[ẽ_j, ĉ]` (`normalised` holds the elements).
    pub fn fold_context(&self, encoded: &[f64], normalised: &[f64], bias: &mut [f64]) {
        let (mlp_bias, mut rest) = bias.split_at_mut(self.mlp.folded_bias_len());
        self.mlp.fold_trailing_inputs(encoded, mlp_bias);
        let mut trailing = Vec::new();
        for (set, net) in &self.local {
            for j in 0..set.count {
                let element = set.start + j * set.size;
                trailing.clear();
                trailing.extend_from_slice(&normalised[element..element + set.size]);
                trailing.extend_from_slice(encoded);
                let (element_bias, tail) = rest.split_at_mut(net.folded_bias_len());
                net.fold_trailing_inputs(&trailing, element_bias);
                rest = tail;
            }
        }
    }

    /// `p_k` at `kept` into `features` (`K W_ψ` entries), keeping the `ψ` activations in
    /// `record` when given.
    fn pool<S: Scalar>(
        &self,
        kept: &[S],
        local_bias: &[f64],
        features: &mut [S],
        feature: &mut [S],
        scratches: &mut [MlpScratch<S>],
        mut record: Option<&mut [f64]>,
    ) {
        let mut biases = local_bias;
        let pooled = features.chunks_exact_mut(self.local_width);
        for (((set, net), pooled), scratch) in self.local.iter().zip(pooled).zip(scratches) {
            pooled.fill(S::constant(0.0));
            let weight = 1.0 / set.count as f64;
            for _ in 0..set.count {
                let (bias, rest) = biases.split_at(net.folded_bias_len());
                biases = rest;
                let len = S::LANES * net.record_len();
                let element_record = record.take().map(|r| r.split_at_mut(len));
                let element_record = element_record.map(|(mine, rest)| {
                    record = Some(rest);
                    mine
                });
                net.eval_folded(kept, bias, scratch, feature, element_record);
                for (p, f) in pooled.iter_mut().zip(feature.iter()) {
                    *p += *f * weight;
                }
            }
        }
    }

    /// `p`'s `P` tangent planes at the recorded point into `features`: per element, its
    /// `ψ_k`'s planes from `sweep` (given the element's `P` record planes) into `feature`,
    /// averaged over the set. `P = 1`: along `dx` from an `f64` record
    /// ([`Mlp::tangent`]); `P = 2`: along `dx + dẋ ε₂` from a `Dual<f64>` one
    /// ([`Mlp::second_tangent`]).
    fn pool_tangents<const P: usize>(
        &self,
        local_record: &[f64],
        features: [&mut [f64]; P],
        feature: &mut [Vec<f64>; P],
        scratches: &mut [MlpScratch<Dual<f64>>],
        sweep: impl Fn(&Mlp, &[f64], &mut MlpScratch<Dual<f64>>, [&mut [f64]; P]),
    ) {
        let mut record = local_record;
        let mut pooled = features.map(|f| f.chunks_exact_mut(self.local_width));
        for ((set, net), scratch) in self.local.iter().zip(scratches) {
            let mut sums = pooled
                .each_mut()
                .map(|p| p.next().expect("one pooled feature per set"));
            sums.iter_mut().for_each(|sum| sum.fill(0.0));
            let weight = 1.0 / set.count as f64;
            for _ in 0..set.count {
                let (mine, rest) = record.split_at(P * net.record_len());
                record = rest;
                sweep(net, mine, scratch, feature.each_mut().map(|f| &mut f[..]));
                for (sum, f) in sums.iter_mut().zip(feature.iter()) {
                    for (s, f) in sum.iter_mut().zip(f) {
                        *s += f * weight;
                    }
                }
            }
        }
    }

    /// The MLP's leading inputs along `dx`, `[dx, ∂p/∂x_k dx]`, into
    /// `scratch.input_tangent[0]`.
    fn tangent_input(
        &self,
        local_record: &[f64],
        dx: &[f64],
        scratch: &mut ConditionerTangentScratch,
    ) {
        let (head, features) = scratch.input_tangent[0].split_at_mut(self.kept);
        head.copy_from_slice(dx);
        self.pool_tangents(
            local_record,
            [features],
            std::array::from_mut(&mut scratch.feature_tangent[0]),
            &mut scratch.local,
            |net, record, scratch, [out]| net.tangent(record, dx, scratch, out),
        );
    }

    /// `θ` at the kept coordinates `kept` for the context folded into `bias`; keeps the
    /// (primal) hidden activations in `record` (of [`record_len`](Self::record_len)) when
    /// given, for [`tangent`](Self::tangent).
    pub fn eval<S: Scalar>(
        &self,
        kept: &[S],
        bias: &[f64],
        scratch: &mut ConditionerScratch<S>,
        theta: &mut [S],
        record: Option<&mut [f64]>,
    ) {
        let (mlp_bias, local_bias) = bias.split_at(self.mlp.folded_bias_len());
        if self.local.is_empty() {
            return self
                .mlp
                .eval_folded(kept, mlp_bias, &mut scratch.mlp, theta, record);
        }
        let (mlp_record, local_record) = match record {
            Some(r) => {
                let (m, l) = r.split_at_mut(S::LANES * self.mlp.record_len());
                (Some(m), Some(l))
            }
            None => (None, None),
        };
        let ConditionerScratch {
            input,
            feature,
            mlp,
            local,
        } = scratch;
        let (head, features) = input.split_at_mut(self.kept);
        head.copy_from_slice(kept);
        self.pool(kept, local_bias, features, feature, local, local_record);
        self.mlp
            .eval_folded(input, mlp_bias, mlp, theta, mlp_record);
    }

    /// The Jacobian-vector product `dθ = ∂θ/∂x_k · dx` at the point of the recorded
    /// [`eval`](Self::eval) (the context is fixed).
    pub fn tangent(
        &self,
        record: &[f64],
        dx: &[f64],
        scratch: &mut ConditionerTangentScratch,
        dtheta: &mut [f64],
    ) {
        let (mlp_record, local_record) = record.split_at(self.mlp.record_len());
        if self.local.is_empty() {
            return self.mlp.tangent(mlp_record, dx, &mut scratch.mlp, dtheta);
        }
        self.tangent_input(local_record, dx, scratch);
        self.mlp.tangent(
            mlp_record,
            &scratch.input_tangent[0],
            &mut scratch.mlp,
            dtheta,
        );
    }

    /// [`eval`](Self::eval) at `kept` and the [`tangent`](Self::tangent) `dθ` at the
    /// recorded point, the MLP multiplying both at once.
    #[allow(clippy::too_many_arguments)]
    pub fn eval_and_tangent(
        &self,
        kept: &[f64],
        bias: &[f64],
        theta: &mut [f64],
        record: &[f64],
        dx: &[f64],
        dtheta: &mut [f64],
        scratch: &mut ConditionerTangentScratch,
    ) {
        let (mlp_bias, local_bias) = bias.split_at(self.mlp.folded_bias_len());
        let (mlp_record, local_record) = record.split_at(self.mlp.record_len());
        if self.local.is_empty() {
            return self.mlp.eval_and_tangent(
                kept,
                mlp_bias,
                theta,
                mlp_record,
                dx,
                dtheta,
                &mut scratch.mlp,
            );
        }
        self.tangent_input(local_record, dx, scratch);
        let primal = &mut scratch.primal;
        let (head, features) = primal.input.split_at_mut(self.kept);
        head.copy_from_slice(kept);
        let feature = &mut primal.feature;
        self.pool(kept, local_bias, features, feature, &mut primal.local, None);
        self.mlp.eval_and_tangent(
            &primal.input,
            mlp_bias,
            theta,
            mlp_record,
            &scratch.input_tangent[0],
            dtheta,
            &mut scratch.mlp,
        );
    }

    /// The second-order tangent `dθ + dθ̇ ε₂ = ∂θ/∂x_k (x_k + ẋ_k ε₂) · (dx + dẋ ε₂)` at
    /// the point of a recorded `Dual<f64>` [`eval`](Self::eval) (the context is fixed),
    /// as `[dθ, dθ̇]` in `scratch` ([`Mlp::second_tangent`]).
    pub fn second_tangent<'s>(
        &self,
        record: &[f64],
        dx: [&[f64]; 2],
        scratch: &'s mut ConditionerTangentScratch,
    ) -> [&'s [f64]; 2] {
        let (mlp_record, local_record) = record.split_at(2 * self.mlp.record_len());
        if self.local.is_empty() {
            return self.mlp.second_tangent(mlp_record, dx, &mut scratch.mlp);
        }
        let [input, input_dot] = &mut scratch.input_tangent;
        let (head, features) = input.split_at_mut(self.kept);
        let (head_dot, features_dot) = input_dot.split_at_mut(self.kept);
        head.copy_from_slice(dx[0]);
        head_dot.copy_from_slice(dx[1]);
        self.pool_tangents(
            local_record,
            [features, features_dot],
            &mut scratch.feature_tangent,
            &mut scratch.local,
            |net, record, scratch, out| {
                for (out, plane) in out.into_iter().zip(net.second_tangent(record, dx, scratch)) {
                    out.copy_from_slice(plane);
                }
            },
        );
        let [input, input_dot] = &scratch.input_tangent;
        self.mlp
            .second_tangent(mlp_record, [input, input_dot], &mut scratch.mlp)
    }
}
