//! A simulator step allocates nothing: an engine steps thousands of environments per
//! request, on every core, and a heap allocation per environment-step costs more than the
//! point mass's whole step (a copy of the torque command in every `StepReport` made the
//! obstacle task's step 10–20 % slower).
//!
//! The heap allocations of this thread are counted by this test binary's global allocator
//! ([`ciflow_engine::allocations`]), so other tests' threads do not disturb the count.

use ciflow_engine::allocations::{CountingAllocator, count_allocations};
use ciflow_engine::math::DVector;
use ciflow_engine::robot::{PANDA_HOME, PointMass2d, panda};
use ciflow_engine::sim::{SimConfig, Simulator};

#[global_allocator]
static ALLOCATOR: CountingAllocator = CountingAllocator;

#[test]
fn a_step_allocates_nothing() {
    let arms: [(Simulator, Vec<f64>); 2] = [
        (
            Simulator::new(Box::new(panda()), SimConfig::default()).unwrap(),
            PANDA_HOME.to_vec(),
        ),
        (
            Simulator::new(
                Box::new(PointMass2d::new(1.0).unwrap()),
                SimConfig::default(),
            )
            .unwrap(),
            vec![0.1, -0.2],
        ),
    ];
    for (mut sim, q0) in arms {
        let dof = q0.len();
        sim.reset(&q0, &vec![0.0; dof]).unwrap();
        let qdd_desired = vec![0.5; dof];
        let mut torque = vec![0.0; dof];
        // The first step may size what the controller keeps between steps.
        sim.step(&qdd_desired).unwrap();
        let made = count_allocations(|| {
            for _ in 0..100 {
                let report = sim.step(&qdd_desired).unwrap();
                assert!(report.end_stops.is_empty());
                torque.copy_from_slice(sim.controller().command().as_slice());
                sim.step_torque(&torque).unwrap();
            }
        });
        assert_eq!(made, 0, "{dof} joints: 200 steps allocated {made} times");
    }
}

/// Negative control: the counter sees a copy of a torque vector, the allocation the
/// simulator's step used to make.
#[test]
fn the_counter_sees_a_vector_copy() {
    let torque = DVector::from_element(7, 1.0);
    let made = count_allocations(|| {
        let copy = std::hint::black_box(torque.clone());
        assert_eq!(copy.len(), 7);
    });
    assert_eq!(made, 1);
}
