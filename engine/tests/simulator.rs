//! The simulator: energy conservation, end stops, perturbation windows, substeps, errors.

mod common;

use ciflow_engine::algorithm::DynamicsError;
use ciflow_engine::control::ControlError;
use ciflow_engine::math::{DVector, Real, Vector3};
use ciflow_engine::model::JointLimits;
use ciflow_engine::robot::{PANDA_HOME, PointMass2d, Robot, panda};
use ciflow_engine::sim::{
    Integrator, Perturbation, PerturbationKind, SimConfig, SimError, Simulator,
};
use common::*;

/// Relative drift of the kinetic energy of the free (gravity-free, torque-free,
/// limit-free) Panda over `seconds`.
fn free_motion_energy_drift(integrator: Integrator, seconds: Real) -> Real {
    let mut robot = panda();
    robot.set_gravity(Vector3::zeros()).unwrap();
    robot.set_limits(JointLimits::unlimited(7)).unwrap();
    let mut probe = robot.clone();
    let config = SimConfig {
        integrator,
        ..SimConfig::default()
    };
    let mut sim = Simulator::new(Box::new(robot), config).unwrap();
    let qd0 = [0.8, -0.6, 1.0, 0.7, -1.2, 0.9, 1.5];
    sim.reset(&PANDA_HOME, &qd0).unwrap();
    let energy = |sim: &Simulator, probe: &mut dyn Robot| {
        let m = mass_matrix(probe, sim.q());
        0.5 * sim.qd().dot(&(m * sim.qd()))
    };
    let e0 = energy(&sim, &mut probe);
    let steps = (seconds / config.physics_dt).round() as usize;
    let mut drift: Real = 0.0;
    for _ in 0..steps {
        sim.step_torque(&[0.0; 7]).unwrap();
        drift = drift.max((energy(&sim, &mut probe) - e0).abs() / e0);
    }
    drift
}

#[test]
fn rk4_conserves_energy_in_free_motion() {
    let drift = free_motion_energy_drift(Integrator::Rk4, 5.0);
    assert!(drift < 1e-6, "RK4 relative energy drift {drift:e}");
}

#[test]
fn semi_implicit_euler_keeps_energy_bounded() {
    let drift = free_motion_energy_drift(Integrator::SemiImplicitEuler, 5.0);
    assert!(
        drift < 5e-2,
        "semi-implicit Euler relative energy drift {drift:e}"
    );
    assert!(
        drift > free_motion_energy_drift(Integrator::Rk4, 5.0),
        "RK4 is the more accurate"
    );
}

#[test]
fn end_stops_clamp_position_and_stop_outward_velocity() {
    let mut limits = JointLimits::unlimited(2);
    limits.q_min = DVector::from_row_slice(&[-1.0, -1.0]);
    limits.q_max = DVector::from_row_slice(&[1.0, 1.0]);
    let robot = PointMass2d::new(1.0).unwrap().with_limits(limits).unwrap();
    let mut sim = Simulator::new(Box::new(robot), SimConfig::default()).unwrap();
    sim.reset(&[0.9, 0.0], &[1.0, 0.0]).unwrap();
    let mut hit = None;
    for k in 0..200 {
        let report = sim.step(&[5.0, 0.0]).unwrap();
        assert!(sim.q()[0] <= 1.0);
        if report.end_stops.contains(0) {
            hit.get_or_insert(k);
            assert_eq!(sim.q()[0], 1.0);
            assert_eq!(sim.qd()[0], 0.0);
        }
        assert!(!report.end_stops.contains(1));
    }
    assert!(hit.is_some(), "the mass reached the stop");
    // Pulling back leaves the stop at once.
    let report = sim.step(&[-5.0, 0.0]).unwrap();
    assert!(report.end_stops.is_empty() && sim.q()[0] < 1.0);
}

/// A robot whose limits are all infinite skips the end-stop and speed checks; one whose
/// finite limits are never reached runs them. Both must move alike, bit for bit, and a
/// speed limit that is exceeded must be reported (for its joint only).
#[test]
fn infinite_limits_never_act_and_finite_speed_limits_are_reported() {
    let far = |bound: Real| {
        let mut limits = JointLimits::unlimited(2);
        limits.q_min = DVector::from_element(2, -1e6);
        limits.q_max = DVector::from_element(2, 1e6);
        limits.qd_max = DVector::from_element(2, bound);
        limits
    };
    let simulator = |limits: Option<JointLimits>| {
        let robot = PointMass2d::new(1.5).unwrap();
        let robot = match limits {
            Some(limits) => robot.with_limits(limits).unwrap(),
            None => robot,
        };
        let mut sim = Simulator::new(Box::new(robot), SimConfig::default()).unwrap();
        sim.reset(&[0.3, -0.2], &[0.1, 0.4]).unwrap();
        sim
    };
    let (mut unlimited, mut checked) = (simulator(None), simulator(Some(far(1e6))));
    for k in 0..300 {
        let action = [
            3.0 * (0.05 * k as Real).sin(),
            -2.0 * (0.03 * k as Real).cos(),
        ];
        let (a, b) = (
            unlimited.step(&action).unwrap(),
            checked.step(&action).unwrap(),
        );
        assert_eq!(unlimited.q(), checked.q());
        assert_eq!(unlimited.qd(), checked.qd());
        assert_eq!(a, b);
        assert!(a.end_stops.is_empty() && a.over_speed.is_empty());
    }
    let mut slow = far(0.5);
    slow.qd_max[1] = Real::INFINITY;
    let mut sim = simulator(Some(slow));
    let report = (0..1000)
        .map(|_| sim.step(&[2.0, 2.0]).unwrap())
        .find(|report| !report.over_speed.is_empty())
        .expect("joint 0 passes 0.5 m/s within 1 s");
    assert!(sim.qd()[0] > 0.5);
    assert!(report.over_speed.contains(0) && !report.over_speed.contains(1));
}

#[test]
fn perturbations_act_only_in_their_window() {
    let mass = 2.0;
    let mut sim = Simulator::new(
        Box::new(PointMass2d::new(mass).unwrap()),
        SimConfig::default(),
    )
    .unwrap();
    sim.reset(&[0.0, 0.0], &[0.0, 0.0]).unwrap();
    let force = 4.0;
    sim.perturb(Perturbation {
        kind: PerturbationKind::LinkWrench {
            link: 0,
            force: [force, 0.0, 0.0],
            torque: [0.0; 3],
        },
        start: 0.0105,
        duration: 0.01,
    })
    .unwrap();
    for _ in 0..40 {
        let before = sim.qd()[0];
        let time = sim.time();
        sim.step(&[0.0, 0.0]).unwrap();
        let pushed = (0.0105..0.0205).contains(&time);
        let expected = if pushed { force / mass * 1e-3 } else { 0.0 };
        assert!(
            (sim.qd()[0] - before - expected).abs() < 1e-15,
            "t = {time}"
        );
    }
    assert!(
        (sim.qd()[0] - force / mass * 0.01).abs() < 1e-12,
        "impulse of 10 ms"
    );
}

/// `perturbed` flags exactly the control periods in which the force changed the velocity.
#[test]
fn perturbed_periods_are_those_the_force_acted_in() {
    let config = SimConfig {
        physics_dt: 0.001,
        control_dt: 0.005,
        ..SimConfig::default()
    };
    let mut sim = Simulator::new(Box::new(PointMass2d::new(1.0).unwrap()), config).unwrap();
    sim.reset(&[0.0, 0.0], &[0.0, 0.0]).unwrap();
    let (start, duration) = (0.0123, 0.0101);
    sim.perturb(Perturbation {
        kind: PerturbationKind::JointTorque(vec![3.0, 0.0]),
        start,
        duration,
    })
    .unwrap();
    assert!(!sim.perturbed(), "nothing acted before a step");
    let mut flagged = Vec::new();
    for _ in 0..20 {
        let before = sim.qd()[0];
        sim.step(&[0.0, 0.0]).unwrap();
        let pushed = sim.qd()[0] != before;
        assert_eq!(sim.perturbed(), pushed, "t = {}", sim.time());
        flagged.push(pushed);
    }
    // The force acts from 12.3 ms to 22.4 ms: periods [10, 15) to [20, 25) ms.
    let expected: Vec<bool> = (0..20).map(|k| (2..=4).contains(&k)).collect();
    assert_eq!(flagged, expected);
}

#[test]
fn link_wrench_equals_its_jacobian_transpose_torque() {
    let q0 = PANDA_HOME;
    let robot = panda();
    let (force, torque) = (Vector3::new(0.0, 15.0, -5.0), Vector3::new(1.0, 0.0, 0.5));
    let mut tau = DVector::zeros(7);
    robot
        .wrench_to_joint_torque(&q0, 6, &force, &torque, &mut tau)
        .unwrap();
    let run = |kind: PerturbationKind| {
        let mut sim = Simulator::new(Box::new(panda()), SimConfig::default()).unwrap();
        sim.reset(&q0, &[0.0; 7]).unwrap();
        sim.perturb(Perturbation {
            kind,
            start: 0.0,
            duration: 1.0,
        })
        .unwrap();
        sim.step(&[0.0; 7]).unwrap();
        sim.qd().clone()
    };
    let by_wrench = run(PerturbationKind::LinkWrench {
        link: 6,
        force: force.into(),
        torque: torque.into(),
    });
    let by_torque = run(PerturbationKind::JointTorque(tau.as_slice().to_vec()));
    assert_close(
        by_wrench.as_slice(),
        by_torque.as_slice(),
        1e-14,
        "wrench vs Jᵀ w",
    );
    assert!(by_wrench.norm() > 1e-4, "the push moved the arm");
}

#[test]
fn control_period_spans_whole_physics_substeps() {
    let config = SimConfig {
        physics_dt: 1e-3,
        control_dt: 5e-3,
        integrator: Integrator::Rk4,
    };
    let mut sim = Simulator::new(Box::new(PointMass2d::new(1.0).unwrap()), config).unwrap();
    sim.reset(&[0.0, 0.0], &[0.0, 0.0]).unwrap();
    let report = sim.step(&[2.0, -1.0]).unwrap();
    assert!((report.time - 5e-3).abs() < 1e-15);
    // Constant acceleration for 5 ms: q = ½ a t².
    assert_close(
        sim.q().as_slice(),
        &[0.5 * 2.0 * 25e-6, -0.5 * 25e-6],
        1e-12,
        "q after 5 ms",
    );
}

#[test]
fn bad_configuration_and_input_are_typed_errors() {
    let robot = || Box::new(panda());
    let bad_ratio = SimConfig {
        physics_dt: 1e-3,
        control_dt: 1.5e-3,
        ..SimConfig::default()
    };
    assert!(matches!(
        Simulator::new(robot(), bad_ratio),
        Err(SimError::NotAMultiple { .. })
    ));
    let bad_dt = SimConfig {
        physics_dt: f64::NAN,
        ..SimConfig::default()
    };
    assert!(matches!(
        Simulator::new(robot(), bad_dt),
        Err(SimError::InvalidTimeStep {
            name: "physics_dt",
            ..
        })
    ));
    let mut sim = Simulator::new(robot(), SimConfig::default()).unwrap();
    assert!(matches!(
        sim.reset(&[0.0; 6], &[0.0; 7]),
        Err(SimError::Dynamics(DynamicsError::Dimension {
            quantity: "q0",
            expected: 7,
            actual: 6
        }))
    ));
    assert!(matches!(
        sim.reset(&[0.0; 7], &[0.0; 7]),
        Err(SimError::OutsideLimits { joint: 3, .. })
    ));
    sim.reset(&PANDA_HOME, &[0.0; 7]).unwrap();
    let mut nan = [0.0; 7];
    nan[2] = f64::NAN;
    assert!(matches!(
        sim.step(&nan),
        Err(SimError::Control(ControlError::Dynamics(
            DynamicsError::NonFinite {
                quantity: "qdd",
                index: 2
            }
        )))
    ));
    let window = |kind| Perturbation {
        kind,
        start: 0.0,
        duration: 1.0,
    };
    assert!(
        sim.perturb(window(PerturbationKind::JointTorque(vec![1.0; 3])))
            .is_err()
    );
    assert!(matches!(
        sim.perturb(window(PerturbationKind::LinkWrench {
            link: 7,
            force: [1.0; 3],
            torque: [0.0; 3]
        })),
        Err(SimError::InvalidPerturbation(_))
    ));
    assert!(matches!(
        sim.perturb(Perturbation {
            duration: -1.0,
            ..window(PerturbationKind::JointTorque(vec![0.0; 7]))
        }),
        Err(SimError::InvalidPerturbation(_))
    ));
    // Windows that can no longer act: empty, or over by the time they are scheduled.
    let in_window = |start, duration| Perturbation {
        start,
        duration,
        ..window(PerturbationKind::JointTorque(vec![0.0; 7]))
    };
    assert!(sim.perturb(in_window(0.5, 0.0)).is_err(), "empty window");
    assert_eq!(sim.time(), 0.0, "failed steps do not advance time");
    sim.step(&[0.0; 7]).unwrap();
    let now = sim.time();
    for (start, duration) in [(-1.0, 0.5), (now - 0.5, 0.2)] {
        assert!(
            matches!(
                sim.perturb(in_window(start, duration)),
                Err(SimError::InvalidPerturbation(_))
            ),
            "[{start}, {}) is over at {now}",
            start + duration
        );
    }
    assert!(
        sim.perturbations().is_empty(),
        "rejected perturbations are not scheduled"
    );
    // A window that began before now but still runs is accepted.
    sim.perturb(in_window(now - 0.5, 0.6)).unwrap();
}

#[test]
fn perturbations_and_config_round_trip_through_json() {
    let perturbation = Perturbation {
        kind: PerturbationKind::LinkWrench {
            link: 3,
            force: [1.0, 2.0, 3.0],
            torque: [0.0, -1.0, 0.5],
        },
        start: 0.25,
        duration: 0.1,
    };
    let json = serde_json::to_string(&perturbation).unwrap();
    assert_eq!(
        serde_json::from_str::<Perturbation>(&json).unwrap(),
        perturbation
    );
    let config = SimConfig {
        integrator: Integrator::Rk4,
        control_dt: 2e-3,
        ..SimConfig::default()
    };
    let json = serde_json::to_string(&config).unwrap();
    assert_eq!(serde_json::from_str::<SimConfig>(&json).unwrap(), config);
    let partial: SimConfig = serde_json::from_str(r#"{"integrator": "Rk4"}"#).unwrap();
    assert_eq!(partial.physics_dt, 1e-3);
}
