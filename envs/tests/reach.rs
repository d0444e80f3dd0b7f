//! `ciflow/Reach-v0` on arms given by URDF: the environment carries the URDF's content,
//! its goals are reachable and inside its context space, its expert reaches them on a
//! UR5e and a KUKA iiwa 14, and bad arguments are typed errors.

use ciflow_envs::env::{Env, EnvError, ResetOptions, SUCCESS_INFO};
use ciflow_envs::registry::{self, Kwarg, Kwargs};
use ciflow_envs::tasks::reach::{self, SUCCESS_RADIUS};

const UR5E: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../engine/tests/assets/ur5e.urdf"
);
const IIWA14: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../engine/tests/assets/iiwa14.urdf"
);
const UR5E_HOME: &str = "0,-1.57,1.57,-1.57,-1.57,0";

/// `NAME=VALUE` pairs read as the command line and Python read them.
fn arguments(pairs: &[(&str, &str)]) -> Result<Kwargs, EnvError> {
    let pairs: Vec<_> = pairs
        .iter()
        .map(|(k, v)| (k.to_string(), v.to_string()))
        .collect();
    registry::entry("reach")?.arguments(&pairs)
}

fn ur5e() -> Kwargs {
    arguments(&[("urdf", UR5E), ("tool", "tool0"), ("home", UR5E_HOME)]).unwrap()
}

#[test]
fn the_environment_holds_the_urdf_document_not_its_path() {
    let kwargs = ur5e();
    let Some(Kwarg::Text(urdf)) = kwargs.get("urdf") else {
        panic!("urdf is not a text: {kwargs:?}");
    };
    assert_eq!(urdf, &std::fs::read_to_string(UR5E).unwrap());
    assert!(!urdf.contains(UR5E));
    // The document itself is taken as it is.
    let again = arguments(&[("urdf", urdf)]).unwrap();
    assert_eq!(again["urdf"], kwargs["urdf"]);
    let env = reach::make(&kwargs).unwrap();
    assert_eq!(env.spec().action_space.dim(), 6);
    assert_eq!(env.spec().observation_space.dim(), 6 + 6 + 3);
    // The default arm is the Panda.
    assert_eq!(
        reach::make(&Kwargs::new())
            .unwrap()
            .spec()
            .action_space
            .dim(),
        7
    );
}

#[test]
fn goals_are_drawn_in_the_context_space_and_replay_with_their_seed() {
    let mut env = reach::make(&ur5e()).unwrap();
    let mut twin = reach::make(&ur5e()).unwrap();
    let space = env.spec().context_space.clone();
    for seed in 0..50 {
        let (observation, _) = env.reset(Some(seed), &ResetOptions::default()).unwrap();
        let (again, _) = twin.reset(Some(seed), &ResetOptions::default()).unwrap();
        assert_eq!(observation, again, "seed {seed}");
        assert!(
            space.contains(&observation[12..]),
            "seed {seed}: {observation:?}"
        );
    }
    // The box is the arm's reach about its home posture: decimetres, not metres.
    let widths: Vec<f64> = (0..3).map(|i| space.high[i] - space.low[i]).collect();
    assert!(widths.iter().all(|w| (0.1..2.0).contains(w)), "{widths:?}");
}

/// The expert's share of `episodes` goals it ends within [`SUCCESS_RADIUS`] of.
fn expert_success(kwargs: &Kwargs, episodes: u64) -> f64 {
    let mut env = reach::make(kwargs).unwrap();
    let mut reached = 0;
    for seed in 0..episodes {
        env.reset(Some(1000 + seed), &ResetOptions::default())
            .unwrap();
        let last = loop {
            let step = env.step(&env.expert_action().unwrap()).unwrap();
            if step.truncated || step.terminated {
                break step;
            }
        };
        assert!(last.info["distance_to_target"] >= 0.0);
        reached += (last.info[SUCCESS_INFO] == 1.0) as u64;
    }
    reached as f64 / episodes as f64
}

#[test]
fn the_expert_reaches_its_goals_on_arms_that_are_not_the_panda() {
    assert_eq!(expert_success(&ur5e(), 20), 1.0);
    let iiwa = arguments(&[("urdf", IIWA14)]).unwrap();
    assert_eq!(expert_success(&iiwa, 20), 1.0);
}

#[test]
fn a_zero_action_does_not_reach_the_goal() {
    // Negative control of the success flag: the arm left alone ends away from its goals.
    let mut env = reach::make(&ur5e()).unwrap();
    let mut reached = 0;
    for seed in 0..10 {
        env.reset(Some(seed), &ResetOptions::default()).unwrap();
        let zero = vec![0.0; 6];
        let last = loop {
            let step = env.step(&zero).unwrap();
            if step.truncated {
                break step;
            }
        };
        reached += (last.info["distance_to_target"] < SUCCESS_RADIUS) as u32;
    }
    assert!(reached <= 1, "{reached} of 10 goals reached without moving");
}

#[test]
fn a_push_moves_the_arm_off_its_unpushed_twin() {
    let mut options = ResetOptions::default();
    let mut pushed = reach::make(&ur5e()).unwrap();
    let mut calm = reach::make(&ur5e()).unwrap();
    options.extra.insert("push_force".into(), 60.0);
    pushed.reset(Some(4), &options).unwrap();
    calm.reset(Some(4), &ResetOptions::default()).unwrap();
    let (mut largest, mut flagged) = (0.0_f64, false);
    for _ in 0..300 {
        let a = pushed.step(&pushed.expert_action().unwrap()).unwrap();
        let b = calm.step(&calm.expert_action().unwrap()).unwrap();
        flagged |= a.info["perturbed"] == 1.0;
        let gap = (0..6)
            .map(|i| (a.observation[i] - b.observation[i]).abs())
            .fold(0.0, f64::max);
        largest = largest.max(gap);
    }
    assert!(flagged, "the push was never reported");
    assert!(largest > 1e-3, "largest joint gap {largest}");
}

#[test]
fn bad_arguments_are_typed_errors() {
    let invalid = |pairs: &[(&str, &str)], key: &str| {
        let result = arguments(pairs).and_then(|kwargs| reach::make(&kwargs).map(|_| ()));
        match result {
            Err(EnvError::InvalidOption { name, detail }) => {
                assert_eq!(name, key, "{pairs:?}: {detail}")
            }
            other => panic!("{pairs:?}: expected InvalidOption on {key}, got {other:?}"),
        }
    };
    invalid(&[("urdf", "/nonexistent/arm.urdf")], "urdf");
    invalid(&[("urdf", "<robot")], "urdf");
    invalid(&[("tool", "tool0")], "tool");
    // Each error names the argument at fault, not the URDF it was applied to.
    invalid(&[("urdf", UR5E), ("tool", "nowhere")], "tool");
    invalid(&[("urdf", UR5E), ("home", "0,0")], "home");
    invalid(&[("urdf", UR5E), ("home", "0,0,0,0,0,x")], "home");
    invalid(&[("urdf", UR5E), ("home", "0,-9,0,0,0,0")], "home");
    invalid(&[("urdf", UR5E), ("home", "0,nan,0,0,0,0")], "home");
    invalid(&[("urdf", UR5E), ("armature", "0.1")], "armature");
    invalid(&[("urdf", UR5E), ("armature", "-1,0,0,0,0,0")], "armature");
    invalid(&[("urdf", UR5E), ("lock_joints", "=1")], "lock_joints");
    invalid(
        &[("urdf", UR5E), ("lock_joints", "no_such_joint")],
        "lock_joints",
    );
    invalid(&[("colour", "red")], "colour");
    // No joint left to move: none in the URDF, or all of them locked.
    invalid(
        &[("urdf", r#"<robot name="rock"><link name="base"/></robot>"#)],
        "urdf",
    );
    let all_locked = "shoulder_pan_joint,shoulder_lift_joint,elbow_joint,wrist_1_joint,\
                      wrist_2_joint,wrist_3_joint";
    invalid(
        &[("urdf", UR5E), ("lock_joints", all_locked)],
        "lock_joints",
    );
}

#[test]
fn the_evaluation_pushes_the_last_link_of_the_urdf_arm() {
    let reach = registry::entry("reach").unwrap();
    assert_eq!(
        reach.pushed_link_with(&Kwargs::new()).unwrap(),
        reach.pushed_link
    );
    assert_eq!(reach.pushed_link_with(&ur5e()).unwrap(), 5);
}
