//! The trait every robot implements: its dynamics and kinematics behind one object-safe
//! interface.

use crate::algorithm::DynamicsError;
use crate::math::{DMatrix, DVector, Isometry3, Real, Vector3};
use crate::model::{Frame, JointLimits};

/// A rigid-body system `M(q) q̈ + C(q, q̇) q̇ + g(q) = τ + τ_ext` with `n = dof()` joints.
///
/// Inputs are slices of length `n` (checked: dimension and finiteness, typed
/// [`DynamicsError`]); outputs go into caller buffers of the right shape, so no method
/// allocates. The dynamics methods take `&mut self` because they use the robot's own
/// workspace; kinematics only reads.
pub trait Robot: Send + Sync {
    fn name(&self) -> &str;

    /// Number of joints `n`.
    fn dof(&self) -> usize;

    fn limits(&self) -> &JointLimits;

    /// Named frames (base, links, tool frames); index into this slice for kinematics.
    fn frames(&self) -> &[Frame];

    /// Index of the tool frame (Panda: the hand; point mass: the mass).
    fn end_effector(&self) -> usize;

    /// Number of movable links that can take an external wrench (link `i` is the body
    /// moved by joint `i`; the point mass has one).
    fn link_count(&self) -> usize;

    fn frame_index(&self, name: &str) -> Option<usize> {
        self.frames().iter().position(|f| f.name == name)
    }

    /// The frame `label` designates: an index into [`frames`](Self::frames), or a name.
    fn find_frame(&self, label: &str) -> Result<usize, DynamicsError> {
        let count = self.frames().len();
        match label.parse::<usize>() {
            Ok(index) if index < count => Ok(index),
            Ok(index) => Err(DynamicsError::NoSuchFrame { index, count }),
            Err(_) => self
                .frame_index(label)
                .ok_or_else(|| DynamicsError::NoFrameNamed {
                    name: label.to_owned(),
                    known: self.frames().iter().map(|f| f.name.clone()).collect(),
                }),
        }
    }

    /// Placement `⁰M_f(q)` of frame `frame` in the base frame.
    fn frame_placement(&self, q: &[Real], frame: usize) -> Result<Isometry3, DynamicsError>;

    /// Geometric Jacobian (6 × n, world-aligned, rows `[linear; angular]`) of the point
    /// `point` given in frame `frame`: `[ṗ; ω] = J q̇`.
    fn frame_jacobian(
        &self,
        q: &[Real],
        frame: usize,
        point: &Vector3,
        jacobian: &mut DMatrix,
    ) -> Result<(), DynamicsError>;

    /// Joint torques `τ = Jᵀ w` of the world-aligned wrench `w = (force, torque)` applied
    /// at the origin of link `link`.
    fn wrench_to_joint_torque(
        &self,
        q: &[Real],
        link: usize,
        force: &Vector3,
        torque: &Vector3,
        tau: &mut DVector,
    ) -> Result<(), DynamicsError>;

    /// Joint-space inertia matrix `M(q)` (n × n, symmetric positive definite).
    fn mass_matrix(&mut self, q: &[Real], m: &mut DMatrix) -> Result<(), DynamicsError>;

    /// Generalized gravity `g(q)`.
    fn gravity(&mut self, q: &[Real], g: &mut DVector) -> Result<(), DynamicsError>;

    /// Coriolis matrix `C(q, q̇)` with `Ṁ = C + Cᵀ`.
    fn coriolis_matrix(
        &mut self,
        q: &[Real],
        qd: &[Real],
        c: &mut DMatrix,
    ) -> Result<(), DynamicsError>;

    /// Nonlinear effects `C(q, q̇) q̇ + g(q)`.
    fn nonlinear_effects(
        &mut self,
        q: &[Real],
        qd: &[Real],
        nle: &mut DVector,
    ) -> Result<(), DynamicsError>;

    /// Inverse dynamics `τ = M(q) q̈ + C(q, q̇) q̇ + g(q)`.
    fn inverse_dynamics(
        &mut self,
        q: &[Real],
        qd: &[Real],
        qdd: &[Real],
        tau: &mut DVector,
    ) -> Result<(), DynamicsError>;

    /// Forward dynamics `q̈ = M(q)⁻¹ (τ − C(q, q̇) q̇ − g(q))`.
    fn forward_dynamics(
        &mut self,
        q: &[Real],
        qd: &[Real],
        tau: &[Real],
        qdd: &mut DVector,
    ) -> Result<(), DynamicsError>;

    /// A hint before a burst of dynamics calls (a control period): bring the workspace
    /// into cache now. Changes no value; by default it does nothing.
    fn prefetch_workspace(&self) {}

    fn boxed_clone(&self) -> Box<dyn Robot>;
}

impl Clone for Box<dyn Robot> {
    fn clone(&self) -> Self {
        self.boxed_clone()
    }
}

impl std::fmt::Debug for dyn Robot {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Robot")
            .field("name", &self.name())
            .field("dof", &self.dof())
            .finish()
    }
}
