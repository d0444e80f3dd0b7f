//! A tapered affine flow tends to one linear map far from the data: its Jacobian is the
//! same in every far direction (`ciflow_engine::flow::layers::taper`). The untapered
//! flow, whose saturated conditioners leave a different scaling in each direction, is the
//! negative control.

mod flow_common;

use ciflow_engine::flow::{CouplingKind, LatentKind};
use flow_common::*;

/// The largest difference between the Jacobians of `f(·, c)` at points `distance` out in
/// a dozen random directions, relative to the largest entry.
fn far_jacobian_spread(coupling: CouplingKind, distance: f64) -> f64 {
    let config = config(3, 2, LatentKind::GoTo, coupling);
    let policy = random_policy(&config, 7);
    let mut r = rng(8);
    let c = uniform(&mut r, 2, 1.0);
    let jacobians: Vec<_> = (0..12)
        .map(|_| {
            let direction = uniform(&mut r, 3, 1.0);
            let norm = direction.iter().map(|v| v * v).sum::<f64>().sqrt();
            let z: Vec<f64> = direction.iter().map(|v| v * distance / norm).collect();
            dual_jacobian(&policy, &z, &c)
        })
        .collect();
    let scale = jacobians.iter().map(|j| j.amax()).fold(0.0, f64::max);
    let spread = jacobians
        .iter()
        .flat_map(|a| jacobians.iter().map(move |b| (a - b).amax()))
        .fold(0.0, f64::max);
    spread / scale
}

#[test]
fn far_from_the_data_a_tapered_flow_is_one_linear_map() {
    // The taper falls as `(R/‖x‖)⁴`; the random weights shrink some coordinates by up to
    // e² per layer on their way, so 1e5 out (spread ≈ 3e-10) rather than 1e4 (≈ 3e-6).
    let tapered = far_jacobian_spread(TAPERED, 1e5);
    assert!(tapered < 1e-6, "tapered: {tapered}");
    let untapered = far_jacobian_spread(CouplingKind::AFFINE, 1e5);
    assert!(untapered > 0.1, "untapered (negative control): {untapered}");
}
