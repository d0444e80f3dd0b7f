//! Chains from modified (Craig) Denavit–Hartenberg parameters.

use super::{Body, Frame, Joint, Model, ModelError};
use crate::math::{Real, Vector3};
use crate::spatial::{Inertia, Se3};

/// Modified DH parameters of one frame: `ᵖMᵢ = RotX(α_{i−1}) TransX(a_{i−1}) TransZ(dᵢ)
/// RotZ(θᵢ)`, with `θᵢ = q_i` for a joint (J. J. Craig, *Introduction to Robotics*, §3.4).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ModifiedDh {
    pub a: Real,
    pub d: Real,
    pub alpha: Real,
}

impl ModifiedDh {
    pub const fn new(a: Real, d: Real, alpha: Real) -> Self {
        Self { a, d, alpha }
    }

    /// The placement `RotX(α) TransX(a) TransZ(d)` of the frame in its parent at `θ = 0`.
    pub fn placement(&self) -> Se3 {
        let rotation = Se3::rotation_about(&Vector3::x(), self.alpha);
        let translation =
            Vector3::new(self.a, 0.0, 0.0) + rotation * Vector3::new(0.0, 0.0, self.d);
        Se3::new(rotation, translation)
    }
}

impl Model {
    /// A chain of revolute joints about their `z` axes from modified DH parameters, one
    /// `(name, parameters, inertia)` per body (inertia in the DH frame of the body);
    /// `extra_frames` are attached as given (e.g. a flange from [`ModifiedDh::placement`]).
    pub fn from_modified_dh(
        name: impl Into<String>,
        base_name: impl Into<String>,
        links: &[(&str, ModifiedDh, Inertia)],
        extra_frames: Vec<Frame>,
    ) -> Result<Model, ModelError> {
        let bodies = links
            .iter()
            .map(|(link, dh, inertia)| Body {
                name: (*link).to_owned(),
                joint: Joint::revolute(format!("{link}_joint"), dh.placement(), Vector3::z()),
                inertia: *inertia,
            })
            .collect();
        Model::new(name, base_name, bodies, extra_frames)
    }
}
