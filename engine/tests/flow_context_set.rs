//! A flow conditioned on an unordered set (obstacle centres) is invariant to the order of
//! the elements and continuous in each of them: moving two obstacles through each other
//! (their x coordinates cross) changes `f`, `f⁻¹` and `log|det ∂f/∂z|` by at most
//! `L |Δc|` along a fine path. The check is run on the conditioning the project used
//! before (elements sorted by x into slots, an order-dependent conditioner) as a negative
//! control, which it must catch.

mod flow_common;

use ciflow_engine::flow::{FlowConfig, Policy};
use flow_common::*;

/// Obstacle `i ∈ {0, 1}` and the target along the path `t ∈ [0, 1]`: the obstacles swap
/// x coordinates at `t = 0.5`, the target stays.
fn crossing(t: f64) -> Vec<f64> {
    let x = -0.4 + 0.8 * t;
    vec![x, 0.15, -x, -0.1, 0.8, 0.05]
}

/// The context the old conditioning fed its conditioners: the elements sorted by x.
fn sorted_by_x(context: &[f64]) -> Vec<f64> {
    let mut sorted = context.to_vec();
    if sorted[2] < sorted[0] {
        sorted.swap(0, 2);
        sorted.swap(1, 3);
    }
    sorted
}

/// `[f(z, c), log|det ∂f/∂z|, f⁻¹(y, c), log|det ∂f⁻¹/∂y|]` at fixed probe points.
fn probe(policy: &Policy, context: &[f64]) -> Vec<f64> {
    let flow = policy.network();
    let mut conditioning = flow.conditioning();
    let mut scratch = flow.scratch();
    flow.condition(context, &mut conditioning, &mut scratch)
        .unwrap();
    let mut out = Vec::new();
    for point in [[0.3, -0.2], [-0.5, 0.4], [0.0, 0.05], [1.2, -0.7]] {
        let (mut image, mut latent) = ([0.0; 2], [0.0; 2]);
        let forward = flow.forward(&point, &conditioning, &mut scratch, &mut image);
        let inverse = flow.inverse(&point, &conditioning, &mut scratch, &mut latent);
        out.extend(
            image
                .iter()
                .chain(&[forward])
                .chain(&latent)
                .chain(&[inverse]),
        );
    }
    out
}

/// `max |probe(c_{i+1}) - probe(c_i)|_∞ / |c_{i+1} - c_i|` over `n` equal steps of the path.
fn steepest_change(policy: &Policy, n: usize, preprocess: impl Fn(&[f64]) -> Vec<f64>) -> f64 {
    let mut previous = probe(policy, &preprocess(&crossing(0.0)));
    let mut steepest = 0.0f64;
    for i in 1..=n {
        let (before, after) = (
            crossing((i - 1) as f64 / n as f64),
            crossing(i as f64 / n as f64),
        );
        let step = max_abs_diff(&before, &after);
        let current = probe(policy, &preprocess(&after));
        steepest = steepest.max(max_abs_diff(&previous, &current) / step);
        previous = current;
    }
    steepest
}

/// The Lipschitz constant `L` a map shows on a path of 2 000 steps, doubled, must bound it
/// on a path of 20 000 steps: a continuous map's difference quotients converge to its
/// derivative as the steps shrink (random weights make steep but continuous maps: one
/// spline variant's quotient grows from 586 at 100 steps to 6 522 at 10 000 and 6 589 at
/// 100 000), while a jump `J` shows as `J / |Δc|`, ten times larger on the fine path.
/// Returns `L_fine / (2 L_coarse)`: at most 1 when continuous, about 5 for a jump.
fn continuity_ratio(policy: &Policy, preprocess: impl Fn(&[f64]) -> Vec<f64> + Copy) -> f64 {
    let coarse = steepest_change(policy, 2_000, preprocess);
    let fine = steepest_change(policy, 20_000, preprocess);
    fine / (2.0 * coarse)
}

fn identity(c: &[f64]) -> Vec<f64> {
    c.to_vec()
}

#[test]
fn moving_obstacles_through_each_other_changes_the_flow_continuously() {
    // The radial contractions about the centres too.
    let configs = [
        obstacle_set(AFFINE),
        obstacle_set(SPLINE),
        contracted(SPLINE),
    ];
    for (k, config) in configs.iter().enumerate() {
        let policy = random_policy(config, 7 + k as u64);
        let ratio = continuity_ratio(&policy, identity);
        assert!(ratio <= 1.0, "variant {k}: fine / (2 L_coarse) = {ratio}");
    }
}

#[test]
fn sorted_slots_jump_where_the_obstacles_cross_and_the_check_catches_it() {
    for (k, coupling) in [AFFINE, SPLINE].into_iter().enumerate() {
        // The same context, no set: the conditioners see the slots in the order given.
        let mut config: FlowConfig = obstacle_set(coupling.clone());
        config.context_sets.clear();
        config.set_encoder = None;
        let policy = random_policy(&config, 7 + k as u64);
        // Without sorting it is continuous too: the check flags the sorting, not the model.
        assert!(continuity_ratio(&policy, identity) <= 1.0);
        let ratio = continuity_ratio(&policy, sorted_by_x);
        assert!(
            ratio > 3.0,
            "coupling {k}: the sorted slots' jump went unseen ({ratio})"
        );
    }
}

#[test]
fn the_order_of_the_obstacles_does_not_matter() {
    for config in [obstacle_set(SPLINE), contracted(SPLINE)] {
        let policy = random_policy(&config, 3);
        let context = crossing(0.3);
        let mut swapped = context.clone();
        swapped.swap(0, 2);
        swapped.swap(1, 3);
        let (a, b) = (probe(&policy, &context), probe(&policy, &swapped));
        assert!(max_abs_diff(&a, &b) < 1e-12, "{a:?} {b:?}");
        // Not because the set is ignored: moving one obstacle changes the flow.
        let mut moved = context.clone();
        moved[1] += 0.2;
        assert!(max_abs_diff(&a, &probe(&policy, &moved)) > 1e-3);
    }
}
