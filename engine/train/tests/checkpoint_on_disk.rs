//! `train_flow_into` leaves on disk exactly the parameters training kept, and says so.
//! (Its own test binary: libtorch's generator is process-global.)

use ciflow_engine::flow::{CouplingKind, LatentKind};
use ciflow_train::synthetic::Spiral;
use ciflow_train::{Keep, OptimConfig, TrainConfig, train_flow_into};

fn scratch(name: &str) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("ciflow-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

#[test]
fn the_checkpoint_on_disk_is_the_one_kept_and_the_last_reported() {
    let data = Spiral::default().demonstrations(4, 30, 1.5, (0.0, 1.5), 2);
    for keep in [Keep::BestValidation, Keep::Last] {
        let config = TrainConfig {
            coupling: CouplingKind::AFFINE,
            layers: 2,
            hidden: vec![16],
            // A step this large makes the later epochs worse than the first, so that with
            // `Keep::Last` the last epoch has to be written after training.
            optim: OptimConfig {
                epochs: 6,
                batch_size: 16,
                learning_rate: 2.0,
                keep,
                ..OptimConfig::default()
            },
            ..TrainConfig::new("spiral", LatentKind::GoTo)
        };
        let (dir, reference) = (scratch("on-disk"), scratch("kept"));
        let mut written = Vec::new();
        let trained =
            train_flow_into(&dir, &data, &config, |_| {}, |p| written.push(p.epoch)).unwrap();
        trained.save(&reference).unwrap();
        let weights = |d: &std::path::Path| std::fs::read(d.join("weights.safetensors")).unwrap();
        assert_eq!(weights(&dir), weights(&reference), "{keep:?}");
        assert_eq!(
            written.last(),
            Some(&trained.best_epoch),
            "{keep:?}: {written:?}"
        );
        let improved: Vec<usize> = trained
            .history
            .iter()
            .filter(|p| p.improved)
            .map(|p| p.epoch)
            .collect();
        assert!(
            written.starts_with(&improved),
            "{keep:?}: {written:?} vs {improved:?}"
        );
        if keep == Keep::Last {
            assert!(
                written.len() > improved.len(),
                "{written:?}: the final write is untested"
            );
        }
        for d in [dir, reference] {
            std::fs::remove_dir_all(d).unwrap();
        }
    }
}
