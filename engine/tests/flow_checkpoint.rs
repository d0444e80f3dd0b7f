//! Checkpoints round-trip, and every way of loading the wrong thing is a typed error.

mod flow_common;

use ciflow_engine::flow::checkpoint::{self, WEIGHTS_FILE};
use ciflow_engine::flow::{
    BaselineConfig, CheckpointConfig, ContextSet, CouplingKind, FlowError, Goal, LatentKind,
    LocalConfig, Policy, SetEncoderConfig, Tensor, Weights,
};
use flow_common::*;

fn temp_dir(name: &str) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("ciflow-flow-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

#[test]
fn saved_checkpoint_reloads_identically() {
    let config = config(3, 2, LatentKind::GoTo, SPLINE);
    let weights = random_weights(&config, 1);
    let dir = temp_dir("roundtrip");
    checkpoint::write(&dir, &CheckpointConfig::Flow(config.clone()), &weights).unwrap();
    let loaded = Policy::load(&dir, Some("test")).unwrap();
    let original = Policy::new(&config, weights).unwrap();
    let (mut wa, mut wb) = (original.workspace(), loaded.workspace());
    let (mut a, mut b) = (vec![0.0; 3], vec![0.0; 3]);
    original
        .mean_next(&[0.1, 0.2, 0.3], &[0.5, -0.5], &mut wa, &mut a)
        .unwrap();
    loaded
        .mean_next(&[0.1, 0.2, 0.3], &[0.5, -0.5], &mut wb, &mut b)
        .unwrap();
    assert_eq!(a, b);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn wrong_task_model_or_shapes_are_typed_errors() {
    let config = config(3, 2, LatentKind::GoTo, AFFINE);
    let weights = random_weights(&config, 2);
    let dir = temp_dir("errors");
    checkpoint::write(&dir, &CheckpointConfig::Flow(config.clone()), &weights).unwrap();
    assert!(matches!(
        Policy::load(&dir, Some("pouring")),
        Err(FlowError::TaskMismatch { .. })
    ));

    // Same names, different hidden width: shape mismatch.
    let mut wider = config.clone();
    wider.hidden = vec![16, 17];
    assert!(matches!(
        Policy::new(&wider, weights.clone()),
        Err(FlowError::ShapeMismatch { .. })
    ));
    // More layers than the file holds: missing tensor.
    let mut deeper = config.clone();
    deeper.layers += 1;
    assert!(matches!(
        Policy::new(&deeper, weights.clone()),
        Err(FlowError::MissingTensor { .. })
    ));
    // Fewer layers: leftover tensors.
    let mut shallower = config.clone();
    shallower.layers -= 1;
    assert!(matches!(
        Policy::new(&shallower, weights.clone()),
        Err(FlowError::UnexpectedTensor { .. })
    ));
    // A NaN weight.
    let mut poisoned = weights.clone();
    poisoned.insert(
        "latent.log_sigma",
        Tensor {
            shape: vec![3],
            data: vec![0.0, f64::NAN, 0.0],
        },
    );
    assert!(matches!(
        Policy::new(&config, poisoned),
        Err(FlowError::NonFinite { .. })
    ));
    // A baseline checkpoint is not a flow.
    let baseline = BaselineConfig {
        task: "test".into(),
        task_kwargs: Default::default(),
        state_dim: 3,
        context_dim: 2,
        dt: 0.1,
        hidden: vec![8],
        goal: Goal::State {
            value: vec![0.0; 3],
        },
        normalisation: config.normalisation.clone(),
        bounds: config.bounds.clone(),
    };
    let baseline_weights = Weights::random(&baseline.parameter_shapes(), 1.0, &mut rng(3));
    let other = temp_dir("baseline");
    checkpoint::write(
        &other,
        &CheckpointConfig::MlpBaseline(baseline),
        &baseline_weights,
    )
    .unwrap();
    assert!(matches!(
        Policy::load(&other, None),
        Err(FlowError::ModelMismatch { .. })
    ));
    // A truncated weights file.
    std::fs::write(dir.join(WEIGHTS_FILE), b"not a safetensors file").unwrap();
    assert!(matches!(
        Policy::load(&dir, None),
        Err(FlowError::SafeTensors(_))
    ));
    for d in [dir, other] {
        std::fs::remove_dir_all(d).unwrap();
    }
}

#[test]
fn bad_inputs_are_typed_errors() {
    let config = config(2, 1, LatentKind::GoTo, SPLINE);
    let policy = random_policy(&config, 4);
    let mut ws = policy.workspace();
    let mut out = vec![0.0; 2];
    assert!(matches!(
        policy.mean_next(&[0.0, f64::NAN], &[0.0], &mut ws, &mut out),
        Err(FlowError::NonFinite { .. })
    ));
    assert!(matches!(
        policy.mean_next(&[0.0, 0.0], &[f64::INFINITY], &mut ws, &mut out),
        Err(FlowError::NonFinite { .. })
    ));
    assert!(matches!(
        policy.mean_next(&[0.0, 0.0, 0.0], &[0.0], &mut ws, &mut out),
        Err(FlowError::Dimension { .. })
    ));
    assert!(matches!(
        policy.velocity(&[0.0, 0.0], &[0.0, 1.0], &mut ws, &mut out),
        Err(FlowError::Dimension { .. })
    ));
    let mut bad = config.clone();
    bad.normalisation.state_std[0] = 0.0;
    assert!(matches!(
        Policy::new(&bad, random_weights(&config, 4)),
        Err(FlowError::InvalidConfig(_))
    ));
    let mut one_dimensional = config.clone();
    one_dimensional.state_dim = 1;
    match one_dimensional.validate() {
        Err(FlowError::InvalidConfig(why)) => assert!(why.contains("needs at least 2"), "{why}"),
        other => panic!("a 1-D state: {other:?}"),
    }
}

/// A `config.json` written before context sets existed has none; one with sets round-trips
/// them; sets outside the context or overlapping, sets without an encoder (or an encoder
/// without sets) and slots normalised differently are typed errors.
#[test]
fn context_sets_default_to_none_round_trip_and_are_validated() {
    let mut config = config(2, 5, LatentKind::GoTo, SPLINE);
    let mut json = serde_json::to_value(CheckpointConfig::Flow(config.clone())).unwrap();
    json.as_object_mut().unwrap().remove("context_sets");
    let old: CheckpointConfig = serde_json::from_value(json).unwrap();
    assert_eq!(old, CheckpointConfig::Flow(config.clone()));

    let set = |start, count| ContextSet {
        start,
        count,
        size: 2,
    };
    config.context_sets = vec![set(1, 2)];
    config.set_encoder = Some(SetEncoderConfig {
        hidden: vec![8],
        width: 3,
        local: Some(LocalConfig {
            hidden: vec![4],
            width: 2,
        }),
    });
    let text = serde_json::to_string(&CheckpointConfig::Flow(config.clone())).unwrap();
    assert!(text.contains("context_sets"));
    let back: CheckpointConfig = serde_json::from_str(&text).unwrap();
    assert_eq!(back, CheckpointConfig::Flow(config.clone()));
    assert!(config.validate().is_ok());

    let mut invalid = Vec::new();
    for bad in [
        vec![set(2, 2)],
        vec![set(0, 0)],
        vec![set(0, 2), set(3, 1)],
        vec![],
    ] {
        let mut config = config.clone();
        config.context_sets = bad;
        invalid.push(config);
    }
    let mut no_encoder = config.clone();
    no_encoder.set_encoder = None;
    let mut unshared = config.clone();
    unshared.normalisation.context_std[3] = 2.0;
    for config in invalid.into_iter().chain([no_encoder, unshared]) {
        assert!(
            matches!(config.validate(), Err(FlowError::InvalidConfig(_))),
            "{config:?}"
        );
    }
}

/// An untapered affine coupling is written as before the taper existed (so older engines
/// read it) and such a `config.json` reads back untapered; a taper round-trips, and a
/// radius that is not finite and > 0 is a typed error.
#[test]
fn taper_radius_defaults_to_none_round_trips_and_is_validated() {
    let untapered = config(2, 1, LatentKind::GoTo, AFFINE);
    let text = serde_json::to_string(&CheckpointConfig::Flow(untapered.clone())).unwrap();
    assert!(!text.contains("taper_radius"), "{text}");
    let back: CheckpointConfig = serde_json::from_str(&text).unwrap();
    assert_eq!(back, CheckpointConfig::Flow(untapered));

    let tapered = config(2, 1, LatentKind::GoTo, TAPERED);
    let text = serde_json::to_string(&CheckpointConfig::Flow(tapered.clone())).unwrap();
    let back: CheckpointConfig = serde_json::from_str(&text).unwrap();
    assert_eq!(back, CheckpointConfig::Flow(tapered.clone()));
    assert!(tapered.validate().is_ok());
    for radius in [0.0, -1.0, f64::NAN, f64::INFINITY] {
        let mut bad = tapered.clone();
        bad.coupling = CouplingKind::Affine {
            scale_bound: 2.0,
            taper_radius: Some(radius),
        };
        assert!(
            matches!(bad.validate(), Err(FlowError::InvalidConfig(_))),
            "{radius}"
        );
    }
}

/// A training split round-trips, names an episode's role only when seed, start and context
/// all match, and a checkpoint without one (or with a malformed one) says so.
#[test]
fn training_split_round_trips_and_matches_only_the_recorded_start() {
    use checkpoint::split::{EpisodeStart, SPLIT_FILE, SplitRole, TrainingSplit, read_split};
    let dir = temp_dir("split");
    std::fs::create_dir_all(&dir).unwrap();
    assert_eq!(read_split(&dir).unwrap(), None);
    let start = |seed, x: f64| EpisodeStart {
        seed: Some(seed),
        position: vec![x, -x],
        context: vec![0.25, 1.5],
    };
    let split = TrainingSplit {
        fitted: vec![start(0, 0.1), start(2, 0.3)],
        held_out: vec![start(1, 0.2)],
    };
    checkpoint::split::write_split(&dir, &split).unwrap();
    let read = read_split(&dir).unwrap().unwrap();
    assert_eq!(read, split);

    let context = [0.25, 1.5];
    assert_eq!(read.role(2, &[0.3, -0.3], &context), SplitRole::Fitted);
    assert_eq!(read.role(1, &[0.2, -0.2], &context), SplitRole::HeldOut);
    // The seed of a demonstration in another task variant: another start, no match.
    assert_eq!(read.role(1, &[0.2, -0.25], &context), SplitRole::NotInData);
    assert_eq!(
        read.role(1, &[0.2, -0.2], &[0.25, 1.0]),
        SplitRole::NotInData
    );
    assert_eq!(read.role(3, &[0.3, -0.3], &context), SplitRole::NotInData);
    // An episode recorded without a seed matches no evaluated episode.
    let unseeded = TrainingSplit {
        fitted: vec![EpisodeStart {
            seed: None,
            ..start(0, 0.1)
        }],
        held_out: Vec::new(),
    };
    assert_eq!(
        unseeded.role(0, &[0.1, -0.1], &context),
        SplitRole::NotInData
    );

    std::fs::write(dir.join(SPLIT_FILE), "{\"fitted\": 3}").unwrap();
    assert!(matches!(read_split(&dir), Err(FlowError::Json { .. })));
    std::fs::remove_dir_all(&dir).unwrap();
}
