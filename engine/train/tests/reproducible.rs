//! Training is reproducible from its seed. (Its own test binary: libtorch's generator is
//! process-global, so a concurrently running test would interleave draws.)

use ciflow_engine::flow::{CouplingKind, LatentKind};
use ciflow_train::synthetic::Spiral;
use ciflow_train::{OptimConfig, TrainConfig, train_flow};

fn trained_weights(config: &TrainConfig) -> Vec<(String, Vec<f64>)> {
    let data = Spiral::default().demonstrations(4, 30, 1.5, (0.0, 1.5), 2);
    let trained = train_flow(&data, config, |_, _| {}).unwrap();
    let mut named: Vec<(String, Vec<f64>)> = trained
        .var_store
        .variables()
        .into_iter()
        .map(|(name, t)| (name, Vec::<f64>::try_from(t.reshape([-1])).unwrap()))
        .collect();
    named.sort_by(|a, b| a.0.cmp(&b.0));
    named
}

fn max_difference(a: &[(String, Vec<f64>)], b: &[(String, Vec<f64>)]) -> f64 {
    a.iter()
        .zip(b)
        .flat_map(|((_, x), (_, y))| x.iter().zip(y).map(|(p, q)| (p - q).abs()))
        .fold(0.0, f64::max)
}

#[test]
fn training_is_reproducible_from_its_seed() {
    let mut config = TrainConfig {
        coupling: CouplingKind::AFFINE,
        layers: 2,
        hidden: vec![16],
        optim: OptimConfig {
            epochs: 3,
            batch_size: 32,
            ..OptimConfig::default()
        },
        ..TrainConfig::new("spiral", LatentKind::GoTo)
    };
    let first = trained_weights(&config);
    assert_eq!(max_difference(&first, &trained_weights(&config)), 0.0);
    config.optim.seed += 1;
    assert!(max_difference(&first, &trained_weights(&config)) > 0.0);
}
