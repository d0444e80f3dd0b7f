//! Serial chains from URDF (via `urdf-rs`).
//!
//! Revolute, continuous and prismatic joints become bodies; fixed joints, and the joints
//! the caller locks, are lumped: the inertia of a rigidly attached child is added to the
//! body it hangs from and its link is kept as a [`Frame`]. What a chain cannot express is
//! refused with a typed error: floating, planar and spherical joints, branches of moving
//! joints (lock all but one, e.g. a gripper's second finger), joints that move no mass
//! (links without `<inertial>`) and non-finite numbers.

use std::collections::HashMap;

use nalgebra::Rotation3;

use super::{Body, Frame, Joint, JointLimits, Model, ModelError};
use crate::math::{Matrix3, Real, Vector3};
use crate::spatial::{Inertia, Se3};

/// A one-degree-of-freedom joint of a URDF held at `position` (rad or m): the model
/// treats it as fixed there.
#[derive(Clone, Debug, PartialEq)]
pub struct LockedJoint {
    pub name: String,
    pub position: Real,
}

impl std::str::FromStr for LockedJoint {
    type Err = String;

    /// `NAME` (held at 0) or `NAME=POSITION`.
    fn from_str(text: &str) -> Result<Self, String> {
        let (name, position) = match text.split_once('=') {
            None => (text, 0.0),
            Some((name, position)) => {
                let position = position
                    .trim()
                    .parse()
                    .map_err(|_| format!("`{position}` in `{text}` is not a number"))?;
                (name, position)
            }
        };
        let name = name.trim();
        if name.is_empty() {
            return Err(format!("`{text}` names no joint"));
        }
        Ok(Self {
            name: name.to_owned(),
            position,
        })
    }
}

impl Model {
    /// Parses a URDF document (see the module documentation). Position, velocity and
    /// effort limits are read from the `<limit>` tags (continuous joints: no position
    /// limit; an omitted velocity or effort: unlimited).
    pub fn from_urdf_str(urdf: &str) -> Result<Model, ModelError> {
        Self::from_urdf_str_locked(urdf, &[])
    }

    /// [`Model::from_urdf_str`] with the `locked` joints held fixed at their positions.
    pub fn from_urdf_str_locked(urdf: &str, locked: &[LockedJoint]) -> Result<Model, ModelError> {
        let robot = urdf_rs::read_from_string(urdf)?;
        ChainBuilder::new(&robot, locked)?.build()
    }
}

struct ChainBuilder<'a> {
    robot: &'a urdf_rs::Robot,
    links: HashMap<&'a str, &'a urdf_rs::Link>,
    children: HashMap<&'a str, Vec<&'a urdf_rs::Joint>>,
    root: &'a str,
    locked: HashMap<&'a str, Real>,
    bodies: Vec<Body>,
    frames: Vec<Frame>,
    limits: Vec<(Real, Real, Real, Real)>,
}

impl<'a> ChainBuilder<'a> {
    fn new(robot: &'a urdf_rs::Robot, locked: &'a [LockedJoint]) -> Result<Self, ModelError> {
        // Names are how joints are locked and frames found: a second one would shadow the
        // first.
        unique_names("link", robot.links.iter().map(|l| l.name.as_str()))?;
        unique_names("joint", robot.joints.iter().map(|j| j.name.as_str()))?;
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
        let mut held = HashMap::new();
        for lock in locked {
            let lock_error = |reason: String| ModelError::Lock {
                joint: lock.name.clone(),
                reason,
            };
            let joint = robot
                .joints
                .iter()
                .find(|j| j.name == lock.name)
                .ok_or_else(|| lock_error("the URDF has no joint of that name".into()))?;
            if !lock.position.is_finite() {
                return Err(lock_error(format!(
                    "position {} is not finite",
                    lock.position
                )));
            }
            match joint.joint_type {
                urdf_rs::JointType::Continuous => {}
                urdf_rs::JointType::Revolute | urdf_rs::JointType::Prismatic => {
                    let (lower, upper) = (joint.limit.lower, joint.limit.upper);
                    if !(lower..=upper).contains(&lock.position) {
                        return Err(lock_error(format!(
                            "position {} is outside its limits [{lower}, {upper}]",
                            lock.position
                        )));
                    }
                }
                ref other => {
                    return Err(lock_error(format!(
                        "only a revolute, continuous or prismatic joint can be locked; this \
                         one is {}",
                        format!("{other:?}").to_lowercase()
                    )));
                }
            }
            if held.insert(lock.name.as_str(), lock.position).is_some() {
                return Err(lock_error("it is locked twice".into()));
            }
        }
        Ok(Self {
            robot,
            links,
            children,
            root,
            locked: held,
            bodies: Vec::new(),
            frames: Vec::new(),
            limits: Vec::new(),
        })
    }

    fn build(mut self) -> Result<Model, ModelError> {
        self.visit(self.root, None, Se3::identity())?;
        self.check_every_joint_moves_mass()?;
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
            let axis = unit_axis(joint)?;
            let movable = match joint.joint_type {
                urdf_rs::JointType::Fixed => None,
                urdf_rs::JointType::Revolute | urdf_rs::JointType::Continuous => {
                    Some(Joint::revolute(&joint.name, origin, axis))
                }
                urdf_rs::JointType::Prismatic => Some(Joint::prismatic(&joint.name, origin, axis)),
                ref other => {
                    return Err(ModelError::UnsupportedJoint {
                        joint: joint.name.clone(),
                        kind: format!("{other:?}").to_lowercase(),
                    });
                }
            };
            match (movable, self.locked.get(joint.name.as_str())) {
                (None, _) => self.visit(&joint.child.link, body, origin)?,
                (Some(held), Some(&position)) => {
                    self.visit(&joint.child.link, body, held.transform(position))?
                }
                (Some(moving), None) => {
                    self.push_body(joint, moving, body)?;
                    let index = self.bodies.len() - 1;
                    self.visit(&joint.child.link, Some(index), Se3::identity())?;
                }
            }
        }
        Ok(())
    }

    /// Appends the body moved by `joint`, which hangs from `parent` (`None`: the base),
    /// with the joint's limits.
    fn push_body(
        &mut self,
        joint: &urdf_rs::Joint,
        moving: Joint,
        parent: Option<usize>,
    ) -> Result<(), ModelError> {
        if parent != self.bodies.len().checked_sub(1) {
            let sibling = parent.map_or(0, |p| p + 1);
            return Err(ModelError::NotSerialChain(format!(
                "joints `{}` and `{}` both move off {}; lock all but one branch \
                 (e.g. a gripper's second finger)",
                self.bodies[sibling].joint.name,
                joint.name,
                parent.map_or_else(
                    || format!("the base `{}`", self.root),
                    |p| format!("link `{}`", self.bodies[p].name)
                ),
            )));
        }
        let (lower, upper) = match joint.joint_type {
            urdf_rs::JointType::Continuous => (Real::NEG_INFINITY, Real::INFINITY),
            _ => (joint.limit.lower, joint.limit.upper),
        };
        // NaN bounds are refused with the other limits' checks, by the model.
        if lower >= upper {
            return Err(ModelError::NoMotion {
                joint: joint.name.clone(),
                kind: match joint.joint_type {
                    urdf_rs::JointType::Prismatic => "prismatic",
                    _ => "revolute",
                },
                lower,
                upper,
            });
        }
        self.limits.push((
            lower,
            upper,
            unspecified_as_unlimited(joint.limit.velocity),
            unspecified_as_unlimited(joint.limit.effort),
        ));
        self.bodies.push(Body {
            name: joint.child.link.clone(),
            joint: moving,
            inertia: Inertia::zero(),
        });
        Ok(())
    }

    /// A joint whose body and every body after it carry no mass or rotational inertia
    /// (URDF links without `<inertial>`) gives a singular `M(q)`: refused.
    fn check_every_joint_moves_mass(&self) -> Result<(), ModelError> {
        let is_empty = |body: &Body| {
            body.inertia.mass == 0.0 && body.inertia.rotational.iter().all(|&x| x == 0.0)
        };
        let empty_tail = self.bodies.iter().rev().take_while(|b| is_empty(b)).count();
        match self.bodies.len().checked_sub(empty_tail) {
            Some(first) if empty_tail > 0 => Err(ModelError::Massless {
                joint: self.bodies[first].joint.name.clone(),
                link: self.bodies[first].name.clone(),
            }),
            _ => Ok(()),
        }
    }
}

/// The joint's axis, normalised (a locked joint never reaches [`Model::new`]'s check).
fn unit_axis(joint: &urdf_rs::Joint) -> Result<Vector3, ModelError> {
    let axis = Vector3::from(joint.axis.xyz.0);
    if !axis.iter().all(|a| a.is_finite()) {
        return Err(ModelError::NonFinite {
            what: format!("axis of joint `{}`", joint.name),
        });
    }
    match axis.try_normalize(1e-12) {
        Some(unit) => Ok(unit),
        None if joint.joint_type == urdf_rs::JointType::Fixed => Ok(Vector3::z()),
        None => Err(ModelError::ZeroAxis {
            joint: joint.name.clone(),
        }),
    }
}

/// Refuses a second `kind` (link or joint) of the same name.
fn unique_names<'a>(
    kind: &'static str,
    names: impl Iterator<Item = &'a str>,
) -> Result<(), ModelError> {
    let mut seen = std::collections::HashSet::new();
    for name in names {
        if !seen.insert(name) {
            return Err(ModelError::DuplicateName {
                kind,
                name: name.to_owned(),
            });
        }
    }
    Ok(())
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
