//! The LASA loader: 30 shapes × 7 demonstrations that end at the origin.

use ciflow_envs::lasa::{self, LasaError};

#[test]
fn all_thirty_shapes_load_with_seven_demos_ending_at_the_origin() {
    let names = lasa::shape_names().unwrap();
    assert_eq!(names.len(), 30);
    assert!(names.iter().any(|n| n == "Sshape") && names.iter().any(|n| n == "Angle"));
    for name in &names {
        let shape = lasa::load(name).unwrap();
        assert_eq!(&shape.name, name);
        assert_eq!(shape.demos.len(), 7);
        assert!(shape.dt > 0.0 && shape.dt < 0.1);
        for demo in &shape.demos {
            let n = demo.times.len();
            assert!(n > 100 && demo.positions.len() == n && demo.velocities.len() == n);
            let [x, y] = demo.positions[n - 1];
            assert!(x.hypot(y) < 1.0, "{name} ends at ({x}, {y}) mm");
            let reach = demo
                .positions
                .iter()
                .map(|[x, y]| x.hypot(*y))
                .fold(0.0, f64::max);
            assert!(
                reach > 10.0,
                "{name} moves only {reach} mm away from the target"
            );
        }
    }
}

#[test]
fn velocities_are_the_derivative_of_positions() {
    let shape = lasa::load("Angle").unwrap();
    let demo = &shape.demos[0];
    let mut worst: f64 = 0.0;
    let mut scale: f64 = 0.0;
    for i in 1..demo.times.len() - 1 {
        let dt = demo.times[i + 1] - demo.times[i - 1];
        for axis in 0..2 {
            let numeric = (demo.positions[i + 1][axis] - demo.positions[i - 1][axis]) / dt;
            worst = worst.max((numeric - demo.velocities[i][axis]).abs());
            scale = scale.max(demo.velocities[i][axis].abs());
        }
    }
    assert!(
        worst < 0.1 * scale,
        "worst mismatch {worst} mm/s of {scale}"
    );
}

#[test]
fn unknown_shapes_are_typed_errors() {
    assert!(matches!(
        lasa::load("Circle"),
        Err(LasaError::UnknownShape { .. })
    ));
}
