//! The episodes held out for early stopping are new to the model in every respect: the
//! normalisation, the bounds and the latent's starting noise that the flow keeps, and the
//! baseline's normalisation and bounds, are those of the fitted episodes alone. Each is
//! recomputed here from the episodes the checkpoint records as fitted, and the held-out
//! episodes are built to move every one of them.

use std::collections::BTreeSet;

use ciflow_engine::flow::checkpoint::split::{EpisodeStart, TrainingSplit};
use ciflow_engine::flow::{Bounds, Goal, LatentKind, Normalisation};
use ciflow_train::trainer::flow_config;
use ciflow_train::{
    BaselineTrainConfig, Contexts, Demonstrations, Episode, OptimConfig, TrainConfig,
    train_baseline, train_flow,
};

const EPISODES: u64 = 10;
const STEPS: usize = 20;
const VALIDATION_FRACTION: f64 = 0.3;

/// Episode `k` goes in a straight line from `(3j + 1, −j)` to the origin, at a speed
/// growing with `j`, under the context `(2j, 1)`, where `j = k + 1 mod 10`: no two episodes
/// share a statistic, and the largest, `j = 9`, is episode 8, which the split of seed 0
/// holds out (so that the bounds move too; `fitted` checks that they do).
fn demonstrations() -> Demonstrations {
    let episode = |seed: u64| {
        let k = ((seed + 1) % EPISODES) as f64;
        let start = [3.0 * k + 1.0, -k];
        let fraction = |t: usize| (t as f64 / STEPS as f64).powf(1.0 + 0.2 * k);
        let states = (0..=STEPS)
            .map(|t| start.iter().map(|s| s * (1.0 - fraction(t))).collect())
            .collect();
        Episode {
            seed: Some(seed),
            ..Episode::new(states, Contexts::PerEpisode(vec![2.0 * k, 1.0]))
        }
    };
    Demonstrations {
        episodes: (0..EPISODES).map(episode).collect(),
        dt: 0.1,
    }
}

/// One epoch at a learning rate too small to move any parameter from where the trainer
/// started it.
fn optim() -> OptimConfig {
    OptimConfig {
        epochs: 1,
        batch_size: 64,
        learning_rate: 1e-12,
        ..OptimConfig::default()
    }
}

fn seeds(split: &TrainingSplit) -> (BTreeSet<u64>, BTreeSet<u64>) {
    let seeds = |starts: &[EpisodeStart]| starts.iter().map(|s| s.seed.unwrap()).collect();
    (seeds(&split.fitted), seeds(&split.held_out))
}

fn rows<'a>(episodes: &'a [&'a Episode]) -> Vec<(&'a [f64], &'a [f64])> {
    episodes
        .iter()
        .flat_map(|e| e.states.iter().map(move |y| (y.as_slice(), e.context(0))))
        .collect()
}

/// Per-coordinate mean and population standard deviation.
fn moments(values: &[&[f64]]) -> (Vec<f64>, Vec<f64>) {
    let n = values.len() as f64;
    let mean: Vec<f64> = (0..values[0].len())
        .map(|i| values.iter().map(|v| v[i]).sum::<f64>() / n)
        .collect();
    let std = (0..mean.len())
        .map(|i| (values.iter().map(|v| (v[i] - mean[i]).powi(2)).sum::<f64>() / n).sqrt())
        .collect();
    (mean, std)
}

fn expected_statistics(episodes: &[&Episode]) -> (Normalisation, Bounds) {
    let rows = rows(episodes);
    let states: Vec<&[f64]> = rows.iter().map(|(y, _)| *y).collect();
    let contexts: Vec<&[f64]> = rows.iter().map(|(_, c)| *c).collect();
    let ((state_mean, state_std), (context_mean, context_std)) =
        (moments(&states), moments(&contexts));
    // The context's constant second entry keeps the trainer's smallest scale.
    let context_std = context_std.into_iter().map(|s| s.max(1e-6)).collect();
    let extent = |values: &[&[f64]], pick: fn(f64, f64) -> f64| -> Vec<f64> {
        (0..values[0].len())
            .map(|i| values.iter().map(|v| v[i]).reduce(pick).unwrap())
            .collect()
    };
    let bounds = Bounds {
        state_min: extent(&states, f64::min),
        state_max: extent(&states, f64::max),
        context_min: extent(&contexts, f64::min),
        context_max: extent(&contexts, f64::max),
    };
    let normalisation = Normalisation {
        state_mean,
        state_std,
        context_mean,
        context_std,
    };
    (normalisation, bounds)
}

fn assert_close(name: &str, got: &[f64], expected: &[f64]) {
    assert_eq!(got.len(), expected.len(), "{name}");
    for (g, e) in got.iter().zip(expected) {
        assert!(
            (g - e).abs() <= 1e-9 * e.abs().max(1.0),
            "{name}: {got:?} against {expected:?}"
        );
    }
}

fn assert_statistics(got: (&Normalisation, &Bounds), expected: &(Normalisation, Bounds)) {
    let (norm, bounds) = got;
    assert_close("state mean", &norm.state_mean, &expected.0.state_mean);
    assert_close("state std", &norm.state_std, &expected.0.state_std);
    assert_close("context mean", &norm.context_mean, &expected.0.context_mean);
    assert_close("context std", &norm.context_std, &expected.0.context_std);
    assert_close("state min", &bounds.state_min, &expected.1.state_min);
    assert_close("state max", &bounds.state_max, &expected.1.state_max);
    assert_close("context min", &bounds.context_min, &expected.1.context_min);
    assert_close("context max", &bounds.context_max, &expected.1.context_max);
}

/// The fitted episodes, as the checkpoint's split names them; and a check that all of the
/// episodes together would give other statistics, so that the comparison can fail.
fn fitted<'a>(data: &'a Demonstrations, split: &TrainingSplit) -> Vec<&'a Episode> {
    let (fitted, held_out) = seeds(split);
    assert_eq!(
        held_out.len(),
        (VALIDATION_FRACTION * EPISODES as f64).round() as usize
    );
    assert!(fitted.is_disjoint(&held_out));
    let all: Vec<&Episode> = data.episodes.iter().collect();
    let fitted: Vec<&Episode> = data
        .episodes
        .iter()
        .filter(|e| fitted.contains(&e.seed.unwrap()))
        .collect();
    let (with_held_out, without) = (expected_statistics(&all), expected_statistics(&fitted));
    for (a, b) in [
        (&with_held_out.0.state_mean, &without.0.state_mean),
        (&with_held_out.0.context_std, &without.0.context_std),
        (&with_held_out.1.state_max, &without.1.state_max),
    ] {
        assert!(
            a.iter().zip(b).any(|(a, b)| (a - b).abs() > 1e-3),
            "the held-out episodes must move the statistics for this test to tell: {held_out:?}"
        );
    }
    fitted
}

/// The RMS step per coordinate, normalised: the latent noise the trainer starts from.
fn rms_step(episodes: &[&Episode], norm: &Normalisation) -> f64 {
    let (mut squares, mut count) = (0.0, 0.0);
    for e in episodes {
        for w in e.states.windows(2) {
            for ((next, previous), std) in w[1].iter().zip(&w[0]).zip(&norm.state_std) {
                squares += ((next - previous) / std).powi(2);
                count += 1.0;
            }
        }
    }
    (squares / count).sqrt()
}

#[test]
fn a_flow_keeps_the_statistics_of_the_episodes_it_fits() {
    let data = demonstrations();
    let train = TrainConfig {
        layers: 2,
        hidden: vec![8],
        validation_fraction: VALIDATION_FRACTION,
        optim: optim(),
        ..TrainConfig::new("lines", LatentKind::GoTo)
    };
    let trained = train_flow(&data, &train, |_, _| {}).unwrap();
    let fitted = fitted(&data, &trained.split);
    let expected = expected_statistics(&fitted);
    assert_statistics(
        (&trained.config.normalisation, &trained.config.bounds),
        &expected,
    );

    let all: Vec<&Episode> = data.episodes.iter().collect();
    let sigma = rms_step(&fitted, &expected.0);
    let with_held_out = rms_step(&all, &expected_statistics(&all).0);
    assert!(
        (sigma - with_held_out).abs() > 1e-3 * sigma,
        "{sigma} {with_held_out}"
    );
    let log_sigma = trained
        .var_store
        .variables()
        .into_iter()
        .find(|(name, _)| name.ends_with("log_sigma"))
        .expect("the latent's noise is a parameter")
        .1;
    for value in Vec::<f64>::try_from(log_sigma.exp()).unwrap() {
        assert!(
            (value - sigma).abs() < 1e-6 * sigma,
            "latent noise {value} against the fitted episodes' {sigma} (all episodes: {with_held_out})"
        );
    }
}

#[test]
fn the_baseline_keeps_the_statistics_of_the_episodes_it_fits() {
    let data = demonstrations();
    let train = BaselineTrainConfig {
        hidden: vec![8],
        validation_fraction: VALIDATION_FRACTION,
        optim: optim(),
        ..BaselineTrainConfig::new(
            "lines",
            Goal::State {
                value: vec![0.0, 0.0],
            },
        )
    };
    let trained = train_baseline(&data, &train, |_| {}).unwrap();
    let fitted = fitted(&data, &trained.split);
    assert_statistics(
        (&trained.config.normalisation, &trained.config.bounds),
        &expected_statistics(&fitted),
    );
}

/// With nothing held out, every training seed shuffles the episodes differently, yet the
/// statistics are summed in the data's order: the same bits whatever the seed, so that a
/// recipe that fits every demonstration trains as it did before there was a split.
#[test]
fn with_nothing_held_out_the_statistics_do_not_depend_on_the_shuffle() {
    let data = demonstrations();
    let config = |seed| {
        let train = TrainConfig {
            validation_fraction: 0.0,
            optim: OptimConfig { seed, ..optim() },
            ..TrainConfig::new("lines", LatentKind::GoTo)
        };
        flow_config(&data, &train).unwrap()
    };
    let first = config(0);
    for seed in 1..4 {
        let other = config(seed);
        assert_eq!(other.normalisation, first.normalisation, "seed {seed}");
        assert_eq!(other.bounds, first.bounds, "seed {seed}");
    }
    // And those are the statistics of all of the episodes.
    let all: Vec<&Episode> = data.episodes.iter().collect();
    assert_statistics(
        (&first.normalisation, &first.bounds),
        &expected_statistics(&all),
    );
}
