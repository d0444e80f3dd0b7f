//! Gymnasium's seeding rule for `reset`.
//!
//! `reset(Some(seed))` reseeds the episode RNG; `reset(None)` continues from its current
//! state, so a seeded reset followed by unseeded ones replays identically. The very first
//! unseeded reset draws a seed from the operating system, as Gymnasium does.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// The RNG behind `reset`: [`ChaCha8Rng`], portable and reproducible across platforms.
#[derive(Clone, Debug, Default)]
pub struct EpisodeRng {
    rng: Option<ChaCha8Rng>,
}

impl EpisodeRng {
    /// Applies the seeding rule and returns the RNG to draw this episode from.
    pub fn reseed(&mut self, seed: Option<u64>) -> &mut ChaCha8Rng {
        match seed {
            Some(seed) => self.rng.insert(ChaCha8Rng::seed_from_u64(seed)),
            None => self.rng.get_or_insert_with(rand::make_rng),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::RngExt;

    #[test]
    fn seeded_then_unseeded_resets_replay() {
        let draws = |rng: &mut EpisodeRng| {
            let a: f64 = rng.reseed(Some(7)).random();
            let b: f64 = rng.reseed(None).random();
            (a, b)
        };
        let (mut first, mut second) = (EpisodeRng::default(), EpisodeRng::default());
        let (a, b) = draws(&mut first);
        assert_eq!((a, b), draws(&mut second));
        assert_ne!(a, b);
    }
}
