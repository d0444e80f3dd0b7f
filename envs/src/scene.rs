//! What a task looks like at one observation: its bodies as simple solids and curves in
//! the world frame.
//!
//! One description feeds every picture of a task: [`crate::shading`] rasterises it into
//! `render()`'s RGB frames, and the Python viewer (`python -m ciflow.view`) logs the same
//! bodies to Rerun. The tasks' URDFs carry inertias but no visual meshes, so an arm's
//! links are capsules between consecutive joint origins ([`arm_links`]).
//!
//! Coordinates are the task's world frame (the robot's base frame), in the task's length
//! unit (m; LASA's mm); `z` points up.

use ciflow_engine::math::{Isometry3, Vector3};
use ciflow_engine::robot::Robot;
use nalgebra::{Rotation3, Unit, UnitQuaternion};

use crate::error::EnvError;
use crate::raster::{GREY, Rgb};

/// The colour of an arm's links.
pub const ARM_COLOR: Rgb = [165, 170, 180];

/// A solid or a curve.
#[derive(Clone, Debug, PartialEq)]
pub enum Shape {
    /// The points within `radius` of the segment `from–to`.
    Capsule {
        from: Vector3,
        to: Vector3,
        radius: f64,
    },
    /// A solid cylinder whose axis is the pose's `z` axis, base centre at the pose's
    /// origin, `height` along `+z`.
    Cylinder {
        pose: Isometry3,
        radius: f64,
        height: f64,
    },
    /// A box centred at the pose's origin with these half extents along its axes.
    Cuboid {
        pose: Isometry3,
        half_extents: Vector3,
    },
    Sphere {
        centre: Vector3,
        radius: f64,
    },
    /// A polyline (closed back to its first point if `closed`), drawn `radius` thick.
    Curve {
        points: Vec<Vector3>,
        closed: bool,
        radius: f64,
    },
}

impl Shape {
    pub fn sphere(centre: Vector3, radius: f64) -> Self {
        Self::Sphere { centre, radius }
    }
}

/// One named, coloured shape. Names are paths (`robot/link3`, `obstacles/0`) so that a
/// viewer can group them.
#[derive(Clone, Debug, PartialEq)]
pub struct Body {
    pub name: String,
    pub shape: Shape,
    pub color: Rgb,
}

impl Body {
    pub fn new(name: impl Into<String>, shape: Shape, color: Rgb) -> Self {
        Self {
            name: name.into(),
            shape,
            color,
        }
    }
}

/// Every body of a task at one observation.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Scene {
    pub bodies: Vec<Body>,
}

impl Scene {
    /// The body called `name`, if any.
    pub fn body(&self, name: &str) -> Option<&Body> {
        self.bodies.iter().find(|b| b.name == name)
    }
}

/// A point of the plane `z = 0`.
pub fn planar(p: &nalgebra::Vector2<f64>) -> Vector3 {
    Vector3::new(p.x, p.y, 0.0)
}

/// The pose at `from` whose `z` axis points at `to`, and the distance between them: how
/// a cylinder or a capsule from `from` to `to` is placed.
pub fn axis_pose(from: &Vector3, to: &Vector3) -> (Isometry3, f64) {
    let axis = to - from;
    let rotation = UnitQuaternion::rotation_between(&Vector3::z(), &axis).unwrap_or_else(|| {
        // `axis` points straight down (or has no length): turn half a circle about x.
        UnitQuaternion::from_axis_angle(&Unit::new_normalize(Vector3::x()), std::f64::consts::PI)
    });
    (Isometry3::from_parts((*from).into(), rotation), axis.norm())
}

/// A cylinder with its base centre at `from` and its top centre at `to`.
pub fn cylinder_between(from: &Vector3, to: &Vector3, radius: f64) -> Shape {
    let (pose, height) = axis_pose(from, to);
    Shape::Cylinder {
        pose,
        radius,
        height,
    }
}

/// The links of `robot` at `q`: one capsule of `radius` from each frame's origin to the
/// next (`robot/link1`, …), coloured `color`. Frames that coincide (a fixed joint with no
/// offset) give no capsule.
pub fn arm_links(
    robot: &dyn Robot,
    q: &[f64],
    radius: f64,
    color: Rgb,
) -> Result<Vec<Body>, EnvError> {
    let origins = (0..robot.frames().len())
        .map(|f| robot.frame_placement(q, f).map(|m| m.translation.vector))
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| EnvError::Simulation(e.into()))?;
    Ok(origins
        .windows(2)
        .enumerate()
        .filter(|(_, pair)| (pair[1] - pair[0]).norm() > 1e-9)
        .map(|(i, pair)| {
            let shape = Shape::Capsule {
                from: pair[0],
                to: pair[1],
                radius,
            };
            Body::new(format!("robot/link{}", i + 1), shape, color)
        })
        .collect())
}

/// The path a point has taken (an arm's spout or tool): a thin grey curve.
pub fn trail(name: &str, points: &[Vector3]) -> Body {
    let curve = Shape::Curve {
        points: points.to_vec(),
        closed: false,
        radius: 0.002,
    };
    Body::new(name, curve, GREY)
}

/// A flat box under the robot: the table, its top at `z = 0`, spanning `[x0, x1] × [y0, y1]`.
pub fn table(x: (f64, f64), y: (f64, f64), thickness: f64, color: Rgb) -> Body {
    let centre = Vector3::new((x.0 + x.1) / 2.0, (y.0 + y.1) / 2.0, -thickness / 2.0);
    Body::new(
        "table",
        Shape::Cuboid {
            pose: Isometry3::from_parts(centre.into(), Rotation3::identity().into()),
            half_extents: Vector3::new((x.1 - x.0) / 2.0, (y.1 - y.0) / 2.0, thickness / 2.0),
        },
        color,
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use ciflow_engine::robot::panda;

    #[test]
    fn a_cylinder_between_two_points_spans_them_whichever_way_they_point() {
        for to in [
            Vector3::new(0.3, -0.2, 0.5),
            Vector3::new(0.0, 0.0, -1.0),
            Vector3::new(0.0, 0.0, 1.0),
        ] {
            let from = Vector3::new(0.1, 0.2, 0.3);
            let to = from + to;
            let Shape::Cylinder { pose, height, .. } = cylinder_between(&from, &to, 0.1) else {
                panic!("not a cylinder");
            };
            let top = pose * nalgebra::Point3::new(0.0, 0.0, height);
            assert!((top.coords - to).norm() < 1e-12, "{to:?}");
            assert!((pose.translation.vector - from).norm() < 1e-12);
        }
    }

    #[test]
    fn arm_links_join_consecutive_frame_origins() {
        let robot = panda();
        let q = ciflow_engine::robot::PANDA_HOME;
        let links = arm_links(&robot, &q, 0.04, [0, 0, 0]).unwrap();
        assert!(links.len() >= 6, "{}", links.len());
        let end = robot
            .frame_placement(&q, robot.frames().len() - 1)
            .unwrap()
            .translation
            .vector;
        let Shape::Capsule { to, .. } = &links.last().unwrap().shape else {
            panic!("not a capsule");
        };
        assert!((to - end).norm() < 1e-12);
        for pair in links.windows(2) {
            let (Shape::Capsule { to, .. }, Shape::Capsule { from, .. }) =
                (&pair[0].shape, &pair[1].shape)
            else {
                panic!("not capsules");
            };
            assert_eq!(to, from, "the chain is unbroken");
        }
    }
}
