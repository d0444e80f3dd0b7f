//! Which of a dataset's episodes a learning curve's point takes: `ciflow train --subset
//! N` fits them, and `ciflow evaluate --nll-subset N` scores the same ones.

use rand::SeedableRng;

/// Asked for no episode, or for more than there are.
#[derive(Debug, thiserror::Error)]
#[error("asked for {count} episodes, the dataset holds {available}")]
pub struct TooFewEpisodes {
    pub count: usize,
    pub available: usize,
}

/// `count` of `episodes`, in their original order, for learning curves against the amount
/// of data. Where every episode has one context number (the limit cycle's phase) and
/// there are at least `count` distinct ones, the episodes of `count` distinct values spread
/// evenly over their range, both ends included (2 → the lowest and the highest), so more
/// data means more contexts and never a repeat; otherwise drawn without replacement by a
/// generator seeded with `seed`.
pub fn subset<T>(
    episodes: Vec<T>,
    count: usize,
    seed: u64,
    context: impl Fn(&T) -> &[f64],
) -> Result<Vec<T>, TooFewEpisodes> {
    let available = episodes.len();
    if !(1..=available).contains(&count) {
        return Err(TooFewEpisodes { count, available });
    }
    let mut keep = vec![false; available];
    let mut values: Vec<f64> = episodes
        .iter()
        .filter_map(|e| match context(e) {
            [value] => Some(*value),
            _ => None,
        })
        .collect();
    values.sort_by(f64::total_cmp);
    values.dedup();
    let scalar_contexts = episodes.iter().all(|e| context(e).len() == 1);
    if scalar_contexts && values.len() >= count {
        let last = values.len() - 1;
        for i in 0..count {
            let wanted = values[(i * last + (count - 1) / 2) / (count - 1).max(1)];
            let first = episodes.iter().position(|e| context(e)[0] == wanted);
            keep[first.expect("the value came from an episode")] = true;
        }
    } else {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        for i in rand::seq::index::sample(&mut rng, available, count) {
            keep[i] = true;
        }
    }
    Ok(episodes
        .into_iter()
        .zip(keep)
        .filter_map(|(episode, kept)| kept.then_some(episode))
        .collect())
}

#[cfg(test)]
mod tests {
    use super::subset;

    /// The ten limit-cycle training phases, in the order a dataset might hold them.
    fn phases() -> Vec<Vec<f64>> {
        [0.3, 1.0, 0.0, 0.6, 0.1, 0.9, 0.4, 0.7, 0.2, 0.8]
            .map(|c| vec![c])
            .to_vec()
    }

    fn chosen(episodes: Vec<Vec<f64>>, count: usize) -> Vec<f64> {
        subset(episodes, count, 0, |e| e.as_slice())
            .unwrap()
            .into_iter()
            .map(|c| c[0])
            .collect()
    }

    #[test]
    fn scalar_contexts_are_spread_evenly_ends_included_in_the_dataset_order() {
        assert_eq!(chosen(phases(), 2), [1.0, 0.0]);
        assert_eq!(chosen(phases(), 5), [1.0, 0.0, 0.6, 0.2, 0.8]);
        assert_eq!(chosen(phases(), 10), phases().concat());
        // Repeated phases count once: 2 of 20 episodes are still the two ends.
        let doubled = [phases(), phases()].concat();
        assert_eq!(chosen(doubled, 2), [1.0, 0.0]);
    }

    #[test]
    fn other_contexts_are_drawn_at_random_and_too_many_is_an_error() {
        let layouts: Vec<Vec<f64>> = (0..10).map(|i| vec![i as f64, 0.0]).collect();
        let drawn = subset(layouts.clone(), 4, 3, |e| e.as_slice()).unwrap();
        assert_eq!(drawn.len(), 4);
        assert_ne!(drawn, layouts[..4], "not the first four");
        assert_eq!(
            drawn,
            subset(layouts.clone(), 4, 3, |e| e.as_slice()).unwrap()
        );
        assert!(subset(layouts, 11, 3, |e| e.as_slice()).is_err());
    }
}
