//! A serial chain robot: a [`Model`] with its own [`Data`] workspace.
//!
//! Clones share the model and copy only the workspace: thousands of environments of one
//! arm then read one model that stays in cache, and each costs only its `Data`.

use std::path::Path;
use std::sync::Arc;

use super::{DynamicsError, Frame, JointLimits, Robot};
use crate::algorithm;
use crate::math::{DMatrix, DVector, Isometry3, Real, Vector3};
use crate::model::{Data, LockedJoint, Model, ModelError};

/// What a URDF does not say about a robot.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct UrdfOptions {
    /// Joints held fixed (e.g. all but one finger of a gripper).
    pub locked: Vec<LockedJoint>,
    /// The tool frame, a link name; default: the last frame of the model.
    pub tool: Option<String>,
    /// Reflected rotor inertias of the moving joints in chain order (kg·m², or kg for a
    /// prismatic joint), which URDF cannot carry; default: zero.
    pub armature: Option<Vec<Real>>,
}

/// A serial chain of revolute and prismatic joints; [`Robot`] methods run the RNEA / CRBA / Coriolis /
/// forward-dynamics algorithms in a preallocated workspace.
#[derive(Clone, Debug)]
pub struct SerialChain {
    model: Arc<Model>,
    data: Data,
    end_effector: usize,
}

impl SerialChain {
    /// The tool frame is the last frame of the model (the last link if it has no extra
    /// frames); see [`SerialChain::set_end_effector`].
    pub fn new(model: Model) -> Self {
        let data = Data::new(&model);
        let end_effector = model.frames().len() - 1;
        Self {
            model: Arc::new(model),
            data,
            end_effector,
        }
    }

    pub fn from_urdf_str(urdf: &str) -> Result<Self, ModelError> {
        Self::from_urdf(urdf, &UrdfOptions::default())
    }

    /// A URDF document completed by `options`.
    pub fn from_urdf(urdf: &str, options: &UrdfOptions) -> Result<Self, ModelError> {
        let mut chain = Self::new(Model::from_urdf_str_locked(urdf, &options.locked)?);
        if let Some(tool) = &options.tool {
            chain.set_end_effector(tool)?;
        }
        if let Some(armature) = &options.armature {
            chain.set_armature(DVector::from_column_slice(armature))?;
        }
        Ok(chain)
    }

    pub fn from_urdf_file(
        path: impl AsRef<Path>,
        options: &UrdfOptions,
    ) -> Result<Self, ModelError> {
        let path = path.as_ref();
        let urdf = std::fs::read_to_string(path).map_err(|source| ModelError::Read {
            path: path.to_owned(),
            source,
        })?;
        Self::from_urdf(&urdf, options)
    }

    pub fn model(&self) -> &Model {
        &self.model
    }

    /// The workspace, holding the results of the last algorithm calls.
    pub fn data(&self) -> &Data {
        &self.data
    }

    pub fn set_limits(&mut self, limits: JointLimits) -> Result<(), ModelError> {
        Arc::make_mut(&mut self.model).set_limits(limits)
    }

    /// Reflected rotor inertias, one per joint ([`Model::armature`]).
    pub fn set_armature(&mut self, armature: DVector) -> Result<(), ModelError> {
        Arc::make_mut(&mut self.model).set_armature(armature)
    }

    /// Gravity acceleration in the base frame (default `(0, 0, −9.81)`).
    pub fn set_gravity(&mut self, gravity: Vector3) -> Result<(), ModelError> {
        Arc::make_mut(&mut self.model).set_gravity(gravity)
    }

    /// Selects the tool frame by name.
    pub fn set_end_effector(&mut self, frame: &str) -> Result<(), ModelError> {
        self.end_effector = self
            .model
            .frame_index(frame)
            .ok_or_else(|| ModelError::NoSuchFrame(frame.to_owned()))?;
        Ok(())
    }
}

impl Robot for SerialChain {
    fn name(&self) -> &str {
        self.model.name()
    }

    fn dof(&self) -> usize {
        self.model.nv()
    }

    fn limits(&self) -> &JointLimits {
        self.model.limits()
    }

    fn frames(&self) -> &[Frame] {
        self.model.frames()
    }

    fn end_effector(&self) -> usize {
        self.end_effector
    }

    fn link_count(&self) -> usize {
        self.model.nv()
    }

    fn frame_placement(&self, q: &[Real], frame: usize) -> Result<Isometry3, DynamicsError> {
        Ok(algorithm::frame_placement(&self.model, q, frame)?.to_isometry())
    }

    fn frame_jacobian(
        &self,
        q: &[Real],
        frame: usize,
        point: &Vector3,
        jacobian: &mut DMatrix,
    ) -> Result<(), DynamicsError> {
        algorithm::frame_jacobian(&self.model, q, frame, point, jacobian)
    }

    fn wrench_to_joint_torque(
        &self,
        q: &[Real],
        link: usize,
        force: &Vector3,
        torque: &Vector3,
        tau: &mut DVector,
    ) -> Result<(), DynamicsError> {
        algorithm::wrench_to_joint_torque(&self.model, q, link, force, torque, tau)
    }

    fn mass_matrix(&mut self, q: &[Real], m: &mut DMatrix) -> Result<(), DynamicsError> {
        copy_matrix("m", algorithm::crba(&self.model, &mut self.data, q)?, m)
    }

    fn gravity(&mut self, q: &[Real], g: &mut DVector) -> Result<(), DynamicsError> {
        copy_vector(
            "g",
            algorithm::generalized_gravity(&self.model, &mut self.data, q)?,
            g,
        )
    }

    fn coriolis_matrix(
        &mut self,
        q: &[Real],
        qd: &[Real],
        c: &mut DMatrix,
    ) -> Result<(), DynamicsError> {
        copy_matrix(
            "c",
            algorithm::coriolis_matrix(&self.model, &mut self.data, q, qd)?,
            c,
        )
    }

    fn nonlinear_effects(
        &mut self,
        q: &[Real],
        qd: &[Real],
        nle: &mut DVector,
    ) -> Result<(), DynamicsError> {
        copy_vector(
            "nle",
            algorithm::nonlinear_effects(&self.model, &mut self.data, q, qd)?,
            nle,
        )
    }

    fn inverse_dynamics(
        &mut self,
        q: &[Real],
        qd: &[Real],
        qdd: &[Real],
        tau: &mut DVector,
    ) -> Result<(), DynamicsError> {
        copy_vector(
            "tau",
            algorithm::rnea(&self.model, &mut self.data, q, qd, qdd)?,
            tau,
        )
    }

    fn forward_dynamics(
        &mut self,
        q: &[Real],
        qd: &[Real],
        tau: &[Real],
        qdd: &mut DVector,
    ) -> Result<(), DynamicsError> {
        copy_vector(
            "qdd",
            algorithm::forward_dynamics(&self.model, &mut self.data, q, qd, tau)?,
            qdd,
        )
    }

    fn prefetch_workspace(&self) {
        self.data.prefetch();
    }

    fn boxed_clone(&self) -> Box<dyn Robot> {
        Box::new(self.clone())
    }
}

/// Copies an algorithm result into a caller buffer of the same length.
fn copy_vector(
    quantity: &'static str,
    from: &DVector,
    to: &mut DVector,
) -> Result<(), DynamicsError> {
    crate::algorithm::check_len(quantity, to.len(), from.len())?;
    to.copy_from(from);
    Ok(())
}

/// Copies an algorithm result into a caller buffer of the same shape.
fn copy_matrix(
    quantity: &'static str,
    from: &DMatrix,
    to: &mut DMatrix,
) -> Result<(), DynamicsError> {
    crate::algorithm::check_matrix_shape(quantity, to, from.nrows(), from.ncols())?;
    to.copy_from(from);
    Ok(())
}
