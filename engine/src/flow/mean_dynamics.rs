//! The noise-free map `y_{k+1} = F(y_k, c)` of a policy and its desired velocity `ẏ(y, c)`,
//! behind one trait: what rollouts, vector fields and the stability check evaluate,
//! whatever the model.
//!
//! For a flow, `F(y, c) = f(μ(f⁻¹(y, c)), c)` with `μ` the latent's mean step and
//! `ẏ = J_f(z) v(z)` at `z = f⁻¹(y, c)` ([`crate::flow::policy`]); for the
//! behaviour-cloning baseline, `ẏ = MLP(y, c)` and `F(y, c) = y + dt · ẏ`
//! ([`crate::flow::baseline`]).

use crate::math::distance;

use crate::flow::baseline::{BaselineWorkspace, BehaviourCloning};
use crate::flow::checkpoint::config::Bounds;
use crate::flow::error::FlowResult;
use crate::flow::policy::{Policy, PolicyWorkspace};

/// A noise-free closed-form dynamics `y_{k+1} = F(y_k, c)` with a known attractor.
pub trait MeanDynamics {
    type Workspace;
    fn workspace(&self) -> Self::Workspace;
    fn bounds(&self) -> &Bounds;
    /// The joint range the dynamics keeps its states in, `(min, max)`, for a policy built
    /// on a robot's limits ([`crate::flow::layers::joint_range`]); no state lies outside.
    fn state_range(&self) -> Option<(&[f64], &[f64])> {
        None
    }
    fn mean_next(
        &self,
        y: &[f64],
        context: &[f64],
        ws: &mut Self::Workspace,
        out: &mut [f64],
    ) -> FlowResult<()>;
    /// The desired velocity `ẏ(y, c)` (state dimension), what the robot is driven to follow.
    fn velocity(
        &self,
        y: &[f64],
        context: &[f64],
        ws: &mut Self::Workspace,
        out: &mut [f64],
    ) -> FlowResult<()>;
    /// Distance from `y` to the attractor; `scratch` has the state dimension.
    fn attractor_distance(
        &self,
        y: &[f64],
        context: &[f64],
        ws: &mut Self::Workspace,
        scratch: &mut [f64],
    ) -> FlowResult<f64>;
}

impl MeanDynamics for Policy {
    type Workspace = PolicyWorkspace;
    fn workspace(&self) -> PolicyWorkspace {
        Policy::workspace(self)
    }
    fn bounds(&self) -> &Bounds {
        &self.config().bounds
    }
    fn state_range(&self) -> Option<(&[f64], &[f64])> {
        let range = self.config().joint_range.as_ref()?;
        Some((&range.position_min, &range.position_max))
    }
    fn mean_next(
        &self,
        y: &[f64],
        context: &[f64],
        ws: &mut PolicyWorkspace,
        out: &mut [f64],
    ) -> FlowResult<()> {
        Policy::mean_next(self, y, context, ws, out)
    }
    fn velocity(
        &self,
        y: &[f64],
        context: &[f64],
        ws: &mut PolicyWorkspace,
        out: &mut [f64],
    ) -> FlowResult<()> {
        Policy::velocity(self, y, context, ws, out)
    }
    fn attractor_distance(
        &self,
        y: &[f64],
        context: &[f64],
        ws: &mut PolicyWorkspace,
        scratch: &mut [f64],
    ) -> FlowResult<f64> {
        Policy::attractor_distance(self, y, context, ws, scratch)
    }
}

impl MeanDynamics for BehaviourCloning {
    type Workspace = BaselineWorkspace;
    fn workspace(&self) -> BaselineWorkspace {
        BehaviourCloning::workspace(self)
    }
    fn bounds(&self) -> &Bounds {
        &self.config().bounds
    }
    fn mean_next(
        &self,
        y: &[f64],
        context: &[f64],
        ws: &mut BaselineWorkspace,
        out: &mut [f64],
    ) -> FlowResult<()> {
        BehaviourCloning::mean_next(self, y, context, ws, out)
    }
    fn velocity(
        &self,
        y: &[f64],
        context: &[f64],
        ws: &mut BaselineWorkspace,
        out: &mut [f64],
    ) -> FlowResult<()> {
        BehaviourCloning::velocity(self, y, context, ws, out)
    }
    fn attractor_distance(
        &self,
        y: &[f64],
        context: &[f64],
        _: &mut BaselineWorkspace,
        scratch: &mut [f64],
    ) -> FlowResult<f64> {
        self.goal(context, scratch);
        Ok(distance(y, scratch))
    }
}
