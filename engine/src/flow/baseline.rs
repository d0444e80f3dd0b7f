//! Unconstrained behaviour cloning `ỹ_{k+1} = ỹ_k + dt · MLP(ỹ_k, c̃)` (normalised
//! coordinates): the negative control of the stability check. Nothing keeps its rollouts
//! bounded away from the data, so its measured stability can fall below 100%.

use std::path::Path;

use crate::flow::checkpoint;
use crate::flow::checkpoint::config::{BaselineConfig, CheckpointConfig, Goal};
use crate::flow::checkpoint::names::NET;
use crate::flow::checkpoint::weights::Weights;
use crate::flow::error::{FlowError, FlowResult, check_dim, check_input};
use crate::nn::mlp::{Mlp, MlpScratch};

#[derive(Clone, Debug)]
pub struct BehaviourCloning {
    config: BaselineConfig,
    net: Mlp,
}

/// Buffers for [`BehaviourCloning`] calls.
#[derive(Clone, Debug)]
pub struct BaselineWorkspace {
    input: Vec<f64>,
    output: Vec<f64>,
    scratch: MlpScratch<f64>,
}

impl BehaviourCloning {
    pub fn new(config: &BaselineConfig, mut weights: Weights) -> FlowResult<Self> {
        config.validate()?;
        let net = Mlp::from_weights(&mut weights, NET, &config.mlp_sizes())?;
        weights.finish()?;
        Ok(Self {
            config: config.clone(),
            net,
        })
    }

    pub fn load(dir: &Path, expected_task: Option<&str>) -> FlowResult<Self> {
        match checkpoint::read(dir, expected_task)? {
            (CheckpointConfig::MlpBaseline(config), weights) => Self::new(&config, weights),
            (other, _) => Err(FlowError::ModelMismatch {
                expected: "mlp_baseline",
                found: other.model_name(),
            }),
        }
    }

    pub fn config(&self) -> &BaselineConfig {
        &self.config
    }

    pub fn workspace(&self) -> BaselineWorkspace {
        BaselineWorkspace {
            input: vec![0.0; self.net.input_dim()],
            output: vec![0.0; self.net.output_dim()],
            scratch: MlpScratch::new(&self.net),
        }
    }

    /// `y_{k+1} = y_k + dt · σ_y ⊙ MLP(ỹ_k, c̃)`.
    pub fn mean_next(
        &self,
        y: &[f64],
        context: &[f64],
        ws: &mut BaselineWorkspace,
        out: &mut [f64],
    ) -> FlowResult<()> {
        self.eval(y, context, ws, out)?;
        let std = &self.config.normalisation.state_std;
        for (i, o) in out.iter_mut().enumerate() {
            *o = y[i] + self.config.dt * std[i] * ws.output[i];
        }
        Ok(())
    }

    /// The velocity the network predicts, `ẏ = σ_y ⊙ MLP(ỹ, c̃)`.
    pub fn velocity(
        &self,
        y: &[f64],
        context: &[f64],
        ws: &mut BaselineWorkspace,
        out: &mut [f64],
    ) -> FlowResult<()> {
        self.eval(y, context, ws, out)?;
        let std = &self.config.normalisation.state_std;
        for (i, o) in out.iter_mut().enumerate() {
            *o = std[i] * ws.output[i];
        }
        Ok(())
    }

    /// The network on the normalised state and context, into `ws.output`; checks that
    /// `out` has the state dimension.
    fn eval(
        &self,
        y: &[f64],
        context: &[f64],
        ws: &mut BaselineWorkspace,
        out: &[f64],
    ) -> FlowResult<()> {
        let (d, norm) = (self.config.state_dim, &self.config.normalisation);
        check_input("state", d, y)?;
        check_input("context", self.config.context_dim, context)?;
        check_dim("output", d, out)?;
        for (i, slot) in ws.input[..d].iter_mut().enumerate() {
            *slot = (y[i] - norm.state_mean[i]) / norm.state_std[i];
        }
        for (i, slot) in ws.input[d..].iter_mut().enumerate() {
            *slot = (context[i] - norm.context_mean[i]) / norm.context_std[i];
        }
        self.net.eval(&ws.input, &mut ws.scratch, &mut ws.output);
        Ok(())
    }

    /// The demonstrations' goal for context `c`.
    pub fn goal(&self, context: &[f64], out: &mut [f64]) {
        match &self.config.goal {
            Goal::ContextIndices { indices } => {
                for (o, &i) in out.iter_mut().zip(indices) {
                    *o = context[i];
                }
            }
            Goal::State { value } => out.copy_from_slice(value),
        }
    }
}
