//! Generalized gravity (`∂U/∂q` by forward kinematics and subtree first moments) against
//! the RNEA at rest, `g(q) = RNEA(q, 0, 0)`, for gravity in any direction, on an arm with
//! revolute joints and one with a prismatic finger.

mod common;

use ciflow_engine::math::{DVector, Vector3};
use ciflow_engine::robot::{Robot, SerialChain};
use common::*;

fn panda_with_finger() -> SerialChain {
    let path = format!("{}/{PANDA_GRIPPER_URDF}", env!("CARGO_MANIFEST_DIR"));
    SerialChain::from_urdf_file(path, &panda_finger_options()).expect("the URDF loads")
}

#[test]
fn gravity_equals_the_rnea_at_rest_for_any_gravity_direction() {
    let mut rng = rng(40);
    let gravities = [
        Vector3::new(0.0, 0.0, -9.81),
        Vector3::new(3.0, -4.0, 0.5),
        Vector3::new(-1.0, 7.0, 9.0),
    ];
    for mut robot in [ciflow_engine::robot::panda(), panda_with_finger()] {
        let n = robot.dof();
        let zero = DVector::zeros(n);
        for gravity in gravities {
            robot.set_gravity(gravity).unwrap();
            for _ in 0..20 {
                let s = random_state(&robot, &mut rng);
                let g = common::gravity(&mut robot, &s.q);
                let rnea_at_rest = inverse_dynamics(&mut robot, &s.q, &zero, &zero);
                assert!(g.norm() > 1e-3, "gravity is not trivially zero");
                assert_close(
                    g.as_slice(),
                    rnea_at_rest.as_slice(),
                    1e-12,
                    &format!("g(q) = RNEA(q, 0, 0), gravity {gravity:?}, {n} joints"),
                );
            }
        }
    }
}
