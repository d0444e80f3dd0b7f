//! The registry's per-task defaults name real parts of each task: the pushed link is the
//! last movable link its environment accepts a push on, a mid-motion context change
//! replaces no more entries than the context has, and a task's arm has a joint per action.
//! Environments made alike share their spec.

use ciflow_engine::sim::{Perturbation, PerturbationKind};
use ciflow_envs::ResetOptions;
use ciflow_envs::registry::{self, Kwargs, tasks};

fn push(link: usize) -> Perturbation {
    Perturbation {
        kind: PerturbationKind::LinkWrench {
            link,
            force: [1.0, 0.0, 0.0],
            torque: [0.0; 3],
        },
        start: 0.0,
        duration: 0.1,
    }
}

#[test]
fn every_task_is_pushed_on_its_last_movable_link() {
    for task in tasks() {
        let mut env = (task.make)();
        env.reset(Some(0), &ResetOptions::default()).unwrap();
        env.perturb(push(task.pushed_link))
            .unwrap_or_else(|e| panic!("{}: link {}: {e}", task.name, task.pushed_link));
        assert!(
            env.perturb(push(task.pushed_link + 1)).is_err(),
            "{}: link {} is not the last one",
            task.name,
            task.pushed_link
        );
    }
}

#[test]
fn a_moved_context_tail_fits_the_context() {
    for task in tasks() {
        let env = (task.make)();
        let dim = env.spec().context_space.dim();
        if let Some(tail) = task.moved_context_tail {
            assert!((1..=dim).contains(&tail), "{}: {tail} of {dim}", task.name);
        }
    }
}

#[test]
fn a_task_arm_has_a_joint_per_action() {
    let mut arms = 0;
    for task in tasks() {
        if let Some(robot) = task.robot {
            let env = (task.make)();
            assert_eq!(
                robot(&Kwargs::new()).unwrap().dof(),
                env.spec().action_space.dim(),
                "{}",
                task.name
            );
            arms += 1;
        }
    }
    assert_eq!(arms, 2, "pouring and reach drive an arm");
}

#[test]
fn arguments_are_numbers_or_the_index_of_a_named_value() {
    let lasa = registry::entry("lasa").unwrap();
    let pair = |key: &str, text: &str| (key.to_owned(), text.to_owned());
    let shape = ciflow_envs::tasks::lasa::SHAPES[3];
    let values = lasa
        .values(&[pair("shape", shape), pair("noise", "0.5")])
        .unwrap();
    assert_eq!(values["shape"], 3.0);
    assert_eq!(values["noise"], 0.5);
    let unknown = lasa.values(&[pair("shape", "NoSuchShape")]).unwrap_err();
    assert!(unknown.to_string().contains("NoSuchShape"), "{unknown}");
    let obstacles = registry::entry("obstacle-avoidance").unwrap();
    assert!(obstacles.values(&[pair("obstacles", "three")]).is_err());
    // An unknown argument names those the task takes, or says it takes none.
    let bogus: ciflow_envs::registry::Kwargs = [(
        "bogus".to_owned(),
        ciflow_envs::registry::Kwarg::Number(1.0),
    )]
    .into();
    let refused = |task: &str| match (registry::entry(task).unwrap().make_with)(&bogus) {
        Err(error) => error.to_string(),
        Ok(_) => panic!("{task} took `bogus`"),
    };
    assert!(refused("obstacle-avoidance").contains("(known: obstacles)"));
    assert!(refused("limit-cycle").ends_with("this task takes none"));
}

/// Two environments of a task made with the same arguments read one spec (the bounds a
/// step checks its action against stay in cache across a batch); other arguments, another.
#[test]
fn environments_made_alike_share_their_spec() {
    for task in tasks() {
        let (a, b) = ((task.make)(), (task.make)());
        assert!(std::ptr::eq(a.spec(), b.spec()), "{}", task.name);
    }
    let obstacles = |n: f64| {
        let kwargs = Kwargs::from([("obstacles".to_string(), n.into())]);
        registry::make_with("ciflow/Obstacle-v0", &kwargs).unwrap()
    };
    let (one, three) = (obstacles(1.0), obstacles(3.0));
    assert!(!std::ptr::eq(one.spec(), three.spec()));
    assert_ne!(
        one.spec().context_space.dim(),
        three.spec().context_space.dim()
    );
}
