//! Time per call of the Panda's dynamics algorithms and of one simulator step.
//!
//! `cargo bench -p ciflow-engine --bench dynamics`. For scale: Pinocchio (C++) takes about
//! 1.2–1.6 µs for RNEA and 0.6 µs for CRBA of the Panda on the project's machines.

use std::hint::black_box;
use std::time::Duration;

use ciflow_engine::algorithm;
use ciflow_engine::math::DVector;
use ciflow_engine::model::Data;
use ciflow_engine::robot::{PANDA_HOME, Robot, panda};
use ciflow_engine::sim::{Integrator, SimConfig, Simulator};
use criterion::{Criterion, criterion_group, criterion_main};

fn dynamics(c: &mut Criterion) {
    let robot = panda();
    let model = robot.model();
    let mut data = Data::new(model);
    let q = DVector::from_row_slice(&[0.3, -0.5, 0.2, -2.0, 0.4, 1.6, -0.3]);
    let qd = DVector::from_row_slice(&[0.4, -0.3, 0.6, 0.5, -0.7, 0.2, 0.9]);
    let qdd = DVector::from_row_slice(&[1.0, -2.0, 0.5, 3.0, -1.5, 2.5, -0.5]);
    let tau = DVector::from_row_slice(&[5.0, -20.0, 3.0, 10.0, 1.0, 0.5, 0.1]);
    let (q, qd, qdd, tau) = (q.as_slice(), qd.as_slice(), qdd.as_slice(), tau.as_slice());

    let mut group = c.benchmark_group("panda");
    group.bench_function("rnea", |b| {
        b.iter(|| {
            algorithm::rnea(
                model,
                &mut data,
                black_box(q),
                black_box(qd),
                black_box(qdd),
            )
            .map(|t| t[0])
        })
    });
    group.bench_function("crba", |b| {
        b.iter(|| algorithm::crba(model, &mut data, black_box(q)).map(|m| m[(0, 0)]))
    });
    group.bench_function("gravity", |b| {
        b.iter(|| algorithm::generalized_gravity(model, &mut data, black_box(q)).map(|g| g[0]))
    });
    group.bench_function("nonlinear_effects", |b| {
        b.iter(|| {
            algorithm::nonlinear_effects(model, &mut data, black_box(q), black_box(qd))
                .map(|b| b[0])
        })
    });
    group.bench_function("coriolis_matrix", |b| {
        b.iter(|| {
            algorithm::coriolis_matrix(model, &mut data, black_box(q), black_box(qd))
                .map(|c| c[(0, 0)])
        })
    });
    group.bench_function("forward_dynamics", |b| {
        b.iter(|| {
            algorithm::forward_dynamics(
                model,
                &mut data,
                black_box(q),
                black_box(qd),
                black_box(tau),
            )
            .map(|a| a[0])
        })
    });
    group.bench_function("frame_placement_hand", |b| {
        b.iter(|| {
            robot
                .frame_placement(black_box(q), robot.end_effector())
                .map(|p| p.translation.x)
        })
    });
    for (name, integrator) in [
        ("sim_step_euler", Integrator::SemiImplicitEuler),
        ("sim_step_rk4", Integrator::Rk4),
    ] {
        let config = SimConfig {
            integrator,
            ..SimConfig::default()
        };
        let mut sim = Simulator::new(Box::new(panda()), config).unwrap();
        sim.reset(&PANDA_HOME, &[0.0; 7]).unwrap();
        let qdd_desired = [0.0; 7];
        let mut steps = 0;
        group.bench_function(name, |b| {
            b.iter(|| {
                // Stay near home: restart every second of simulated time.
                steps += 1;
                if steps % 1000 == 0 {
                    sim.reset(&PANDA_HOME, &[0.0; 7]).unwrap();
                }
                sim.step(black_box(&qdd_desired)).map(|r| r.time)
            })
        });
    }
    group.finish();
}

fn config() -> Criterion {
    Criterion::default()
        .warm_up_time(Duration::from_millis(300))
        .measurement_time(Duration::from_secs(1))
        .sample_size(30)
}

criterion_group! {
    name = benches;
    config = config();
    targets = dynamics
}
criterion_main!(benches);
