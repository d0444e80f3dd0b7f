//! Serial chains from URDF (via `urdf-rs`).

use std::collections::HashMap;

use nalgebra::Rotation3;

use super::{Body, Frame, JointLimits, Model, ModelError, RevoluteJoint};
use crate::math::{Matrix3, Real, Vector3};
use crate::spatial::{Inertia, Se3};

impl Model {
    /// Parses a URDF document. Revolute and continuous joints become bodies; fixed joints
    /// are lumped: the inertia of a fixed child is added to the body it hangs from and its
    /// link is kept as a [`Frame`]. Position, velocity and effort limits are read from the
    /// `<limit>` tags (continuous joints: no position limit).
    pub fn from_urdf_str(urdf: &str) -> Result<Model, ModelError> {
        let robot = urdf_rs::read_from_string(urdf)?;
        ChainBuilder::new(&robot)?.build()
    }
}

struct ChainBuilder<'a> {
    robot: &'a urdf_rs::Robot,
    links: HashMap<&'a str, &'a urdf_rs::Link>,
    children: HashMap<&'a str, Vec<&'a urdf_rs::Joint>>,
    root: &'a str,
    bodies: Vec<Body>,
    frames: Vec<Frame>,
    limits: Vec<(Real, Real, Real, Real)>,
}

impl<'a> ChainBuilder<'a> {
    fn new(robot: &'a urdf_rs::Robot) -> Result<Self, ModelError> {
        let links: HashMap<_, _> = robot.links.iter().map(|l| (l.name.as_str(), l)).collect();
        let mut children: HashMap<&str, Vec<&urdf_rs::Joint>> = HashMap::new();
        for joint in &robot.joints {
            for link in [&joint.parent.link, &joint.child.link] {
                if !links.contains_key(link.as_str()) {
                    return Err(ModelError::NotSerialChain(format!(
                        "joint `{}` names an unknown link `{link}`",
                        joint.name
                    )));
                }
            }
            children
                .entry(joint.parent.link.as_str())
                .or_default()
                .push(joint);
        }
        let mut roots = robot
            .links
            .iter()
            .filter(|l| !robot.joints.iter().any(|j| j.child.link == l.name));
        let root = match (roots.next(), roots.next()) {
            (Some(root), None) => root.name.as_str(),
            _ => {
                return Err(ModelError::NotSerialChain(
                    "expected exactly one root link".into(),
                ));
            }
        };
        Ok(Self {
            robot,
            links,
            children,
            root,
            bodies: Vec::new(),
            frames: Vec::new(),
            limits: Vec::new(),
        })
    }

    fn build(mut self) -> Result<Model, ModelError> {
        self.visit(self.root, None, Se3::identity())?;
        let mut model = Model::new(&self.robot.name, self.root, self.bodies, self.frames)?;
        let column = |pick: fn(&(Real, Real, Real, Real)) -> Real| {
            self.limits.iter().map(pick).collect::<Vec<_>>().into()
        };
        let unlimited = JointLimits::unlimited(model.nv());
        model.set_limits(JointLimits {
            q_min: column(|l| l.0),
            q_max: column(|l| l.1),
            qd_max: column(|l| l.2),
            tau_max: column(|l| l.3),
            ..unlimited
        })?;
        Ok(model)
    }

    /// Visits `link`, rigidly attached to `body` (`None`: the base) at `placement`.
    fn visit(
        &mut self,
        link: &'a str,
        body: Option<usize>,
        placement: Se3,
    ) -> Result<(), ModelError> {
        let urdf_link = self.links[link];
        if let Some(b) = body {
            self.bodies[b].inertia += placement.act_inertia(&link_inertia(urdf_link));
        }
        let is_body_frame = body.is_some_and(|b| self.bodies[b].name == link);
        if !is_body_frame && link != self.root {
            self.frames.push(Frame {
                name: link.to_owned(),
                body,
                placement,
            });
        }
        let joints = self.children.get(link).cloned().unwrap_or_default();
        for joint in joints {
            let origin = placement * pose(&joint.origin);
            match joint.joint_type {
                urdf_rs::JointType::Fixed => self.visit(&joint.child.link, body, origin)?,
                urdf_rs::JointType::Revolute | urdf_rs::JointType::Continuous => {
                    if body != self.bodies.len().checked_sub(1) {
                        return Err(ModelError::NotSerialChain(format!(
                            "joint `{}` branches off the chain",
                            joint.name
                        )));
                    }
                    self.bodies.push(Body {
                        name: joint.child.link.clone(),
                        joint: RevoluteJoint {
                            name: joint.name.clone(),
                            placement: origin,
                            axis: Vector3::from(joint.axis.xyz.0),
                        },
                        inertia: Inertia::zero(),
                    });
                    let (lower, upper) = match joint.joint_type {
                        urdf_rs::JointType::Continuous => (Real::NEG_INFINITY, Real::INFINITY),
                        _ => (joint.limit.lower, joint.limit.upper),
                    };
                    self.limits.push((
                        lower,
                        upper,
                        unspecified_as_unlimited(joint.limit.velocity),
                        unspecified_as_unlimited(joint.limit.effort),
                    ));
                    let index = self.bodies.len() - 1;
                    self.visit(&joint.child.link, Some(index), Se3::identity())?;
                }
                ref other => {
                    return Err(ModelError::UnsupportedJoint {
                        joint: joint.name.clone(),
                        kind: format!("{other:?}"),
                    });
                }
            }
        }
        Ok(())
    }
}

/// URDF writes `0` for an omitted velocity or effort limit.
fn unspecified_as_unlimited(limit: Real) -> Real {
    if limit > 0.0 { limit } else { Real::INFINITY }
}

/// A URDF `origin` (`xyz`, `rpy` with `R = Rz(yaw) Ry(pitch) Rx(roll)`).
fn pose(origin: &urdf_rs::Pose) -> Se3 {
    let [roll, pitch, yaw] = origin.rpy.0;
    Se3::new(
        Rotation3::from_euler_angles(roll, pitch, yaw).into_inner(),
        Vector3::from(origin.xyz.0),
    )
}

/// The link's `<inertial>` as a spatial inertia in the link frame.
fn link_inertia(link: &urdf_rs::Link) -> Inertia {
    let inertial = &link.inertial;
    let i = &inertial.inertia;
    let inertia_frame = Matrix3::new(
        i.ixx, i.ixy, i.ixz, i.ixy, i.iyy, i.iyz, i.ixz, i.iyz, i.izz,
    );
    let origin = pose(&inertial.origin);
    let inertia_link = origin.rotation * inertia_frame * origin.rotation.transpose();
    Inertia::from_com(inertial.mass.value, origin.translation, inertia_link)
}
