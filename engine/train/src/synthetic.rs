//! Demonstrations from a known stable system, for tests and benchmarks until real datasets
//! are wired in: a latent spiral `ẋ = A x`, `A = [[-a, ω], [-ω, -a]]`, stepped exactly
//! with Gaussian process noise and seen through the diffeomorphism
//! `y = (x₀, x₁ + κ x₀²)`. Its attractor is `y = 0`.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

use crate::data::{Contexts, Demonstrations, Episode};

/// Parameters of the synthetic spiral.
#[derive(Clone, Copy, Debug)]
pub struct Spiral {
    /// Decay rate `a` (1/s).
    pub decay: f64,
    /// Angular velocity `ω` (rad/s).
    pub omega: f64,
    /// Bend `κ` of the observation map.
    pub bend: f64,
    pub dt: f64,
    /// Process-noise standard deviation per step.
    pub noise: f64,
}

impl Default for Spiral {
    fn default() -> Self {
        Self {
            decay: 1.0,
            omega: 2.0,
            bend: 0.5,
            dt: 0.05,
            noise: 0.005,
        }
    }
}

impl Spiral {
    /// One exact noise-free step `x ← exp(A dt) x`.
    pub fn step(&self, x: [f64; 2]) -> [f64; 2] {
        let (r, (s, c)) = (
            (-self.decay * self.dt).exp(),
            (self.omega * self.dt).sin_cos(),
        );
        [r * (c * x[0] + s * x[1]), r * (-s * x[0] + c * x[1])]
    }

    pub fn observe(&self, x: [f64; 2]) -> Vec<f64> {
        vec![x[0], x[1] + self.bend * x[0] * x[0]]
    }

    /// The noise-free observed trajectory of `steps + 1` states from latent start `x`.
    pub fn trajectory(&self, mut x: [f64; 2], steps: usize) -> Vec<Vec<f64>> {
        let mut out = vec![self.observe(x)];
        for _ in 0..steps {
            x = self.step(x);
            out.push(self.observe(x));
        }
        out
    }

    /// `episodes` noisy episodes of `steps` steps started on the circle of radius `radius`
    /// at evenly spaced angles in `[first, last]`; no context.
    pub fn demonstrations(
        &self,
        episodes: usize,
        steps: usize,
        radius: f64,
        (first, last): (f64, f64),
        seed: u64,
    ) -> Demonstrations {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let noise = Normal::new(0.0, self.noise).expect("finite noise");
        let episodes = (0..episodes)
            .map(|e| {
                let angle = first + (last - first) * e as f64 / (episodes.max(2) - 1) as f64;
                let mut x = [radius * angle.cos(), radius * angle.sin()];
                let mut states = vec![self.observe(x)];
                for _ in 0..steps {
                    let next = self.step(x);
                    x = [
                        next[0] + noise.sample(&mut rng),
                        next[1] + noise.sample(&mut rng),
                    ];
                    states.push(self.observe(x));
                }
                Episode::new(states, Contexts::PerEpisode(Vec::new()))
            })
            .collect();
        Demonstrations {
            episodes,
            dt: self.dt,
        }
    }
}
