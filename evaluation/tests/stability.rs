//! Measured stability: 100% for random (untrained) flows of every variant; and the check
//! can fail: it flags the same flows with their latent run backwards in time (a negative
//! control of the same class), in observation space and driving the robot, and the
//! unconstrained behaviour-cloning baseline; and it counts the rollouts that stall at a
//! spurious attractor.

// The engine's flow test fixtures, shared rather than copied.
#[path = "../../engine/tests/flow_common/mod.rs"]
mod flow_common;

use ciflow_engine::flow::MeanDynamics;
use ciflow_engine::flow::{
    BaselineConfig, BehaviourCloning, Bounds, FlowResult, Goal, Normalisation, Policy, Weights,
};
use ciflow_engine::math::distance;
use ciflow_envs::actor::Model;
use ciflow_evaluation::EvaluationError;
use ciflow_evaluation::robot_loop::RobotLoopConfig;
use ciflow_evaluation::stability::{
    Ending, StabilityConfig, StabilityReport, TOLERANCE_FACTORS, measure,
};
use ciflow_evaluation::stability_check::{StabilityCheck, check_stability};
use flow_common::*;

fn check() -> StabilityConfig {
    StabilityConfig {
        starts: 40,
        max_steps: 5_000,
        ..StabilityConfig::default()
    }
}

#[test]
fn random_flows_converge_from_starts_100x_outside_the_data() {
    for (k, config) in variants().iter().enumerate() {
        for seed in 0..2 {
            let policy = random_policy(config, 1000 * k as u64 + seed);
            let report = measure(&policy, &check(), |_| {}).unwrap();
            assert_eq!(report.fraction, 1.0, "variant {k} seed {seed}: {report:?}");
            assert_eq!(report.stalled_away, 0);
        }
    }
}

#[test]
fn the_check_flags_every_rollout_of_the_time_reversed_flows() {
    for (k, config) in variants().iter().enumerate() {
        let policy = random_policy(config, 1000 * k as u64).time_reversed();
        let report = measure(&policy, &check(), |_| {}).unwrap();
        assert_eq!(report.converged, 0, "variant {k}: {report:?}");
    }
}

/// A flow on a robot's joint range starts inside it (no state of it lies outside) and, at
/// random weights, converges from everywhere there; its time-reversed twin is flagged.
#[test]
fn flows_on_a_joint_range_converge_from_across_it() {
    for (k, coupling) in [AFFINE, SPLINE].into_iter().enumerate() {
        let config = ranged(
            config(3, 2, ciflow_engine::flow::LatentKind::GoTo, coupling),
            UNBOUNDED,
        );
        let weights = Weights::random(&config.parameter_shapes(), 0.3, &mut rng(k as u64));
        let policy = ciflow_engine::flow::Policy::new(&config, weights).unwrap();
        let (lo, hi) = policy.state_range().expect("a joint range");
        // Narrower than the start box (100× the unit data box), so the cut acts.
        assert!(lo.iter().zip(hi).all(|(a, b)| b - a < 200.0));
        let report = measure(&policy, &check(), |_| {}).unwrap();
        assert_eq!(report.fraction, 1.0, "coupling {k}: {report:?}");
        let reversed = measure(&policy.time_reversed(), &check(), |_| {}).unwrap();
        assert_eq!(reversed.converged, 0, "coupling {k}: {reversed:?}");
    }
}

/// A behaviour-cloning MLP at random weights, in the unit box around its goal.
fn random_baseline() -> BehaviourCloning {
    let (d, m) = (2, 2);
    let config = BaselineConfig {
        task: "test".into(),
        task_kwargs: Default::default(),
        state_dim: d,
        context_dim: m,
        dt: 0.05,
        hidden: vec![32, 32],
        goal: Goal::ContextIndices {
            indices: vec![0, 1],
        },
        normalisation: Normalisation::identity(d, m),
        bounds: flow_common::config(d, m, ciflow_engine::flow::LatentKind::GoTo, AFFINE).bounds,
    };
    let weights = Weights::random(&config.parameter_shapes(), 1.0, &mut rng(9));
    BehaviourCloning::new(&config, weights).unwrap()
}

#[test]
fn random_behaviour_cloning_does_not_converge_everywhere() {
    let report = measure(&random_baseline(), &check(), |_| {}).unwrap();
    assert!(report.fraction < 1.0, "{report:?}");
    // Looser tolerances can only admit more rollouts.
    assert_eq!(report.within[0].fraction, report.fraction);
    assert!(
        report
            .within
            .windows(2)
            .all(|w| w[0].fraction <= w[1].fraction)
    );
}

/// A hand-made map `y_{k+1} = step(y_k, c)` on the unit state box with its attractor at
/// the origin: what the check must tell apart from a stable flow.
struct Toy {
    bounds: Bounds,
    step: fn(&[f64], &[f64], &mut [f64]),
}

impl Toy {
    /// `context_dim` context coordinates, each with the training box `[−1, 1]`.
    fn new(context_dim: usize, step: fn(&[f64], &[f64], &mut [f64])) -> Self {
        Self {
            bounds: Bounds {
                state_min: vec![-1.0, -1.0],
                state_max: vec![1.0, 1.0],
                context_min: vec![-1.0; context_dim],
                context_max: vec![1.0; context_dim],
            },
            step,
        }
    }
}

impl MeanDynamics for Toy {
    type Workspace = ();
    fn workspace(&self) {}
    fn bounds(&self) -> &Bounds {
        &self.bounds
    }
    fn mean_next(&self, y: &[f64], c: &[f64], _: &mut (), out: &mut [f64]) -> FlowResult<()> {
        (self.step)(y, c, out);
        Ok(())
    }
    /// One step per unit time.
    fn velocity(&self, y: &[f64], c: &[f64], _: &mut (), out: &mut [f64]) -> FlowResult<()> {
        (self.step)(y, c, out);
        for (o, yi) in out.iter_mut().zip(y) {
            *o -= yi;
        }
        Ok(())
    }
    fn attractor_distance(
        &self,
        y: &[f64],
        _: &[f64],
        _: &mut (),
        _: &mut [f64],
    ) -> FlowResult<f64> {
        Ok(distance(y, &[0.0, 0.0]))
    }
}

const SPURIOUS: [f64; 2] = [60.0, 0.0];

/// `y ← y − 0.1 (y − a)` towards the nearer of the attractor at the origin and a spurious
/// fixed point `SPURIOUS`.
fn two_fixed_points(y: &[f64], _: &[f64], out: &mut [f64]) {
    let target = match distance(y, &SPURIOUS) < distance(y, &[0.0, 0.0]) {
        true => SPURIOUS,
        false => [0.0, 0.0],
    };
    for ((o, yi), t) in out.iter_mut().zip(y).zip(target) {
        *o = yi - 0.1 * (yi - t);
    }
}

#[test]
fn rollouts_stalled_at_a_spurious_attractor_are_counted_and_end_there() {
    let model = Toy::new(0, two_fixed_points);
    // Starts up to 100x outside: those with x > 30 are nearer the spurious point.
    let report = measure(&model, &check(), |_| {}).unwrap();
    assert!(report.stalled_away > 0, "{report:?}");
    assert_eq!(
        report.converged + report.stalled_away,
        report.rollouts,
        "{report:?}"
    );
    // They stop where they stalled (60 from the attractor), long before the step budget.
    assert!(
        (report.worst_final_distance - 60.0).abs() < 1e-3,
        "{report:?}"
    );
    // 60 is beyond every tolerance factor's reach (1000 x 2.8e-3): the shares agree.
    assert_eq!(report.within.len(), TOLERANCE_FACTORS.len());
    for share in &report.within {
        assert_eq!(share.fraction, report.fraction, "{report:?}");
    }
}

/// `y ← 0.5 y`: every path runs straight in, inside the box its start was drawn from.
fn halving(y: &[f64], _: &[f64], out: &mut [f64]) {
    for (o, yi) in out.iter_mut().zip(y) {
        *o = 0.5 * yi;
    }
}

/// `y ← A y`, `A = [[0.5, 20], [0, 0.5]]`: both eigenvalues 0.5, so every path converges,
/// but `A` is far from normal and first throws a path out along `x` by up to ~15 times
/// its `y`.
fn shear(y: &[f64], _: &[f64], out: &mut [f64]) {
    out[0] = 0.5 * y[0] + 20.0 * y[1];
    out[1] = 0.5 * y[1];
}

#[test]
fn paths_that_leave_the_start_box_on_the_way_in_are_counted() {
    let straight = measure(&Toy::new(0, halving), &check(), |_| {}).unwrap();
    assert_eq!(straight.fraction, 1.0, "{straight:?}");
    assert_eq!(straight.left_start_box, Some(0), "{straight:?}");
    assert!(
        (50.0..=100.0).contains(&straight.largest_reach.unwrap()),
        "the farthest start of 40 in the 100x box: {straight:?}"
    );
    let thrown = measure(&Toy::new(0, shear), &check(), |_| {}).unwrap();
    assert_eq!(thrown.fraction, 1.0, "stable all the same: {thrown:?}");
    assert!(
        thrown.left_start_box.unwrap() > thrown.rollouts / 2,
        "{thrown:?}"
    );
    assert!(thrown.largest_reach.unwrap() > 500.0, "{thrown:?}");
    // Endings from an engine that does not measure reach leave it unknown, not zero.
    let config = check();
    let endings: Vec<Ending> = (0..config.starts)
        .map(|_| Ending::Converged {
            steps: 3,
            reach: None,
        })
        .collect();
    let unknown = StabilityReport::from_endings(&Toy::new(0, shear), &config, &endings).unwrap();
    assert_eq!(
        (unknown.left_start_box, unknown.largest_reach),
        (None, None)
    );
    let old_reply: Ending = serde_json::from_str(r#"{"ending": "converged", "steps": 3}"#).unwrap();
    assert_eq!(old_reply.reach(), None);
}

/// `y ← 0.5 y` while the context's first coordinate lies in the box `[−1, 1]`, `y ← y`
/// (stuck) beyond it, and `y ← 2 y` (repelled) when its second coordinate leaves the box.
fn context_gate(y: &[f64], c: &[f64], out: &mut [f64]) {
    let gain = match (c[0].abs() <= 1.0, c[1].abs() <= 1.0) {
        (_, false) => 2.0,
        (true, true) => 0.5,
        (false, true) => 1.0,
    };
    for (o, yi) in out.iter_mut().zip(y) {
        *o = gain * yi;
    }
}

#[test]
fn contexts_reach_outside_the_box_except_the_bounded_coordinates() {
    let model = Toy::new(2, context_gate);
    let inside = measure(&model, &check(), |_| {}).unwrap();
    assert_eq!(inside.fraction, 1.0, "{inside:?}");
    let config = StabilityConfig {
        starts: 400,
        context_scale: 10.0,
        bounded_context: vec![1],
        ..check()
    };
    let far = measure(&model, &config, |_| {}).unwrap();
    // c₀ ~ U(−10, 10) lies in [−1, 1] one time in ten; c₁ never leaves the box.
    assert!((0.05..0.15).contains(&far.fraction), "{far:?}");
    assert_eq!(far.diverged_to_non_finite, 0, "{far:?}");
    assert_eq!(far.stalled_away, far.rollouts - far.converged, "{far:?}");
    let unbounded = measure(
        &model,
        &StabilityConfig {
            bounded_context: vec![],
            ..config
        },
        |_| {},
    )
    .unwrap();
    assert!(
        unbounded.diverged_to_non_finite > unbounded.rollouts / 2,
        "{unbounded:?}"
    );
}

#[test]
fn the_report_does_not_depend_on_the_number_of_threads() {
    let policy = random_policy(&variants()[0], 5);
    let report = |threads| {
        let config = StabilityConfig {
            threads,
            starts: 20,
            max_steps: 1_000,
            ..check()
        };
        serde_json::to_string(&measure(&policy.time_reversed(), &config, |_| {}).unwrap()).unwrap()
            + &serde_json::to_string(&measure(&policy, &config, |_| {}).unwrap()).unwrap()
    };
    assert_eq!(report(1), report(3));
}

fn whole_check(negative_control_starts: Option<usize>) -> StabilityCheck {
    StabilityCheck {
        rollouts: StabilityConfig {
            starts: 20,
            ..check()
        },
        far_context_scale: 10.0,
        negative_control_starts,
        robot_loop: None,
    }
}

#[test]
fn the_whole_check_passes_a_flow_and_its_verdict_fails_on_a_converging_control() {
    let model = Model::from(random_policy(&variants()[0], 7));
    let mut stages = Vec::new();
    let report = check_stability(&model, &whole_check(Some(20)), |stage, _, _| {
        if stages.last() != Some(&stage) {
            stages.push(stage);
        }
    })
    .unwrap();
    assert_eq!(
        stages.len(),
        3,
        "training contexts, far contexts, control: {stages:?}"
    );
    assert_eq!(report.observation_space.fraction, 1.0);
    assert_eq!(report.far_contexts.fraction, 1.0);
    assert_eq!(report.far_contexts.context_scale, 10.0);
    assert!(report.verdict().is_ok(), "{report}");
    // The same report with a control that converges (the flow itself) must be refused.
    let flow = model.flow().unwrap();
    let mut missed = report.clone();
    missed.negative_control = Some(measure(flow, &missed.check.rollouts, |_| {}).unwrap());
    let error = missed.verdict().unwrap_err();
    assert_eq!((error.converged, error.rollouts), (20, 20));
}

/// Each count and scale that cannot run is named, before any rollout.
#[test]
fn settings_that_cannot_run_are_named() {
    let model = Toy::new(2, context_gate);
    let refused =
        |config: StabilityConfig| measure(&model, &config, |_| {}).unwrap_err().to_string();
    let message = refused(StabilityConfig {
        max_steps: 0,
        ..check()
    });
    assert!(message.contains("rollout steps, got 0"), "{message}");
    let message = refused(StabilityConfig {
        tolerance: f64::NAN,
        ..check()
    });
    assert!(message.contains("tolerance must be finite"), "{message}");
    let policy = Model::from(random_policy(&variants()[0], 7));
    let mut stages = 0;
    let none = check_stability(&policy, &whole_check(Some(0)), |_, _, _| stages += 1);
    assert!(
        matches!(&none, Err(EvaluationError::InvalidConfig(m)) if m.contains("at least one start")),
        "{none:?}"
    );
    assert_eq!(stages, 0, "refused before the model's rollouts");
}

#[test]
fn the_baseline_has_no_negative_control() {
    let model = Model::from(random_baseline());
    assert!(check_stability(&model, &whole_check(None), |_, _, _| {}).is_ok());
    assert!(matches!(
        check_stability(&model, &whole_check(Some(20)), |_, _, _| {}),
        Err(EvaluationError::InvalidConfig(_))
    ));
}

/// Through the robot as well: a flow drives the task's point mass to its attractor, the
/// same flow with its latent run backwards drives it nowhere near, and the verdict refuses
/// a robot-loop control that converged. The control period is a LASA shape's, which no
/// whole number of 1 ms physics steps fills.
#[test]
fn the_robot_loop_flags_the_time_reversed_flow_driving_the_robot() {
    let mut config = variants()[0].clone();
    config.task = "lasa".into();
    config.dt = 0.002968502735264841;
    // Weights small enough that the motions stay inside the robot's limits, which a
    // converging flow need not do.
    let weights = Weights::random(&config.parameter_shapes(), 0.05, &mut rng(7));
    let model = Model::from(Policy::new(&config, weights).unwrap());
    let with_robot = |negative_control_starts| StabilityCheck {
        robot_loop: Some(RobotLoopConfig {
            starts: 4,
            duration: 60.0,
            ..RobotLoopConfig::default()
        }),
        ..whole_check(negative_control_starts)
    };
    let report = check_stability(&model, &with_robot(Some(20)), |_, _, _| {}).unwrap();
    let robot = report.robot_loop.as_ref().expect("the robot loop ran");
    assert_eq!(robot.fraction, 1.0, "{report}");
    let control = report
        .robot_loop_negative_control
        .as_ref()
        .expect("the control drove the robot too");
    assert_eq!((control.converged, control.rollouts), (0, 4), "{report}");
    assert!(report.verdict().is_ok(), "{report}");
    assert!(report.to_string().contains("robot-loop negative control"));

    let mut missed = report.clone();
    missed.robot_loop_negative_control = report.robot_loop.clone();
    let error = missed.verdict().unwrap_err();
    assert_eq!(
        (error.place, error.converged, error.rollouts),
        ("through the robot", 4, 4)
    );

    let without = check_stability(&model, &with_robot(None), |_, _, _| {}).unwrap();
    assert!(without.robot_loop.is_some() && without.robot_loop_negative_control.is_none());
}
