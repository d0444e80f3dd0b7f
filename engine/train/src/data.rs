//! Demonstrations: episodes of states `[T × d]` with contexts `[T × m]` or one per
//! episode, sampled every `dt` seconds.

use ciflow_engine::flow::checkpoint::split::{EpisodeStart, TrainingSplit};
use ciflow_engine::flow::{Bounds, ContextSet, JointRange, Normalisation};
use tch::{Kind, Tensor};

use crate::error::{TrainError, TrainResult};

/// Contexts of one episode.
#[derive(Clone, Debug, PartialEq)]
pub enum Contexts {
    /// One context per state (`c_t`).
    PerStep(Vec<Vec<f64>>),
    /// One context for the whole episode.
    PerEpisode(Vec<f64>),
}

#[derive(Clone, Debug, PartialEq)]
pub struct Episode {
    /// The seed its recording was reset with, if known.
    pub seed: Option<u64>,
    pub states: Vec<Vec<f64>>,
    pub contexts: Contexts,
    /// Transitions `y_t → y_{t+1}` left out of the likelihood, e.g. those an external force
    /// moved: `T − 1` flags, or none when every transition counts. No modelled span crosses
    /// an excluded transition; the states themselves still start the spans after it.
    pub excluded: Vec<bool>,
}

impl Episode {
    /// An episode whose every transition counts.
    pub fn new(states: Vec<Vec<f64>>, contexts: Contexts) -> Self {
        Self {
            seed: None,
            states,
            contexts,
            excluded: Vec::new(),
        }
    }

    /// How it started: its seed, first state and first context.
    pub fn start(&self) -> EpisodeStart {
        EpisodeStart {
            seed: self.seed,
            position: self.states.first().cloned().unwrap_or_default(),
            context: self.context(0).to_vec(),
        }
    }

    pub fn context(&self, t: usize) -> &[f64] {
        match &self.contexts {
            Contexts::PerStep(c) => &c[t],
            Contexts::PerEpisode(c) => c,
        }
    }

    /// Whether transition `y_t → y_{t+1}` enters the likelihood.
    pub fn counts(&self, t: usize) -> bool {
        !self.excluded.get(t).copied().unwrap_or(false)
    }

    /// For each transition `t`, how many transitions from `t` on count without a break
    /// (0 for an excluded one): the longest span that may start at `y_t`.
    fn counted_runs(&self) -> Vec<i64> {
        let steps = self.states.len().saturating_sub(1);
        let mut runs = vec![0; steps];
        for t in (0..steps).rev() {
            if self.counts(t) {
                runs[t] = 1 + runs.get(t + 1).copied().unwrap_or(0);
            }
        }
        runs
    }
}

#[derive(Clone, Debug, PartialEq)]
pub struct Demonstrations {
    pub episodes: Vec<Episode>,
    pub dt: f64,
}

/// Smallest standard deviation used for normalisation (a constant coordinate keeps scale 1).
const MIN_STD: f64 = 1e-6;

impl Demonstrations {
    /// The mean of the episodes' final states: the go-to goal when the context does not
    /// hold it.
    pub fn mean_final_state(&self) -> Vec<f64> {
        let n = self.episodes.len() as f64;
        let d = self.episodes.first().map_or(0, |e| e.states[0].len());
        let mut goal = vec![0.0; d];
        for e in &self.episodes {
            if let Some(last) = e.states.last() {
                for (g, v) in goal.iter_mut().zip(last) {
                    *g += v / n;
                }
            }
        }
        goal
    }

    /// Checks shapes and values; returns `(d, m)`.
    pub fn validate(&self) -> TrainResult<(usize, usize)> {
        let invalid = |m: String| Err(TrainError::InvalidData(m));
        if !(self.dt.is_finite() && self.dt > 0.0) {
            return invalid("dt must be finite and > 0".into());
        }
        let Some(first) = self.episodes.first() else {
            return invalid("no episodes".into());
        };
        let Some(state) = first.states.first() else {
            return invalid("episode 0 is empty".into());
        };
        let (d, m) = (state.len(), first.context(0).len());
        let counted = |e: &Episode| (0..e.states.len() - 1).filter(|&t| e.counts(t)).count();
        for (e, episode) in self.episodes.iter().enumerate() {
            if episode.states.len() < 2 {
                return invalid(format!("episode {e} has fewer than 2 states"));
            }
            if !episode.excluded.is_empty() && episode.excluded.len() != episode.states.len() - 1 {
                return invalid(format!(
                    "episode {e}: {} exclusion flags for {} transitions",
                    episode.excluded.len(),
                    episode.states.len() - 1
                ));
            }
            if let Contexts::PerStep(c) = &episode.contexts
                && c.len() != episode.states.len()
            {
                return invalid(format!(
                    "episode {e}: {} contexts for {} states",
                    c.len(),
                    episode.states.len()
                ));
            }
            for t in 0..episode.states.len() {
                let (y, c) = (&episode.states[t], episode.context(t));
                if y.len() != d || c.len() != m {
                    return invalid(format!(
                        "episode {e}, step {t}: state/context dimension differs from ({d}, {m})"
                    ));
                }
                if y.iter().chain(c).any(|v| !v.is_finite()) {
                    return invalid(format!("episode {e}, step {t}: non-finite value"));
                }
            }
        }
        if self.episodes.iter().map(counted).sum::<usize>() == 0 {
            return invalid("every transition is excluded".into());
        }
        Ok((d, m))
    }

    /// The episodes fitted and those held out for validation: a seeded shuffle, then the
    /// last `round(fraction · n)` (at least 1, at most `n − 1`) held out; none when
    /// `fraction` is 0 or there is a single episode.
    pub fn split(&self, fraction: f64, seed: u64) -> Split<'_> {
        use rand::SeedableRng;
        use rand::seq::SliceRandom;
        let n = self.episodes.len();
        let mut order: Vec<usize> = (0..n).collect();
        order.shuffle(&mut rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ 0x5eed));
        let held_out = if n >= 2 && fraction > 0.0 {
            ((fraction * n as f64).round() as usize).clamp(1, n - 1)
        } else {
            0
        };
        let (fitted, held_out) = order.split_at(n - held_out);
        let mut fitted_flags = vec![true; n];
        for &i in held_out {
            fitted_flags[i] = false;
        }
        let episodes = |indices: &[usize]| indices.iter().map(|&i| &self.episodes[i]).collect();
        Split {
            fitted: episodes(fitted),
            held_out: episodes(held_out),
            data: &self.episodes,
            fitted_flags,
        }
    }
}

/// The episodes a model is fitted to and those held out to validate it
/// ([`Demonstrations::split`]). What a model keeps of its data besides its weights (the
/// normalisation, the bounds, the latent's starting rates) comes from the fitted episodes
/// alone, so that the held-out ones are new to it in every respect: its early stopping and
/// any score on them take that for granted.
#[derive(Clone, Debug)]
pub struct Split<'a> {
    /// In the shuffled order training takes them.
    pub fitted: Vec<&'a Episode>,
    pub held_out: Vec<&'a Episode>,
    data: &'a [Episode],
    /// Per episode of `data`: whether it is fitted.
    fitted_flags: Vec<bool>,
}

impl<'a> Split<'a> {
    /// The fitted episodes in the data's order, in which their statistics are summed: so
    /// that the statistics do not depend on the shuffle, and a split that holds nothing out
    /// gives those of the whole data bit for bit.
    pub fn fitted_in_data_order(&self) -> impl Iterator<Item = &'a Episode> + Clone + '_ {
        self.data
            .iter()
            .zip(&self.fitted_flags)
            .filter(|(_, fitted)| **fitted)
            .map(|(episode, _)| episode)
    }

    /// How each part's episodes started, as the checkpoint records them.
    pub fn recorded(&self) -> TrainingSplit {
        let starts = |episodes: &[&Episode]| episodes.iter().map(|e| e.start()).collect();
        TrainingSplit {
            fitted: starts(&self.fitted),
            held_out: starts(&self.held_out),
        }
    }

    fn rows(&self) -> impl Iterator<Item = (&[f64], &[f64])> + Clone {
        self.fitted_in_data_order()
            .flat_map(|e| (0..e.states.len()).map(move |t| (e.states[t].as_slice(), e.context(t))))
    }

    /// Per-coordinate mean and standard deviation of the fitted episodes' states (as the
    /// network sees them: through `R⁻¹` under a joint range) and contexts; the slots of
    /// each of `sets` share the statistics of all their elements (so the normalisation does
    /// not depend on the elements' order).
    pub fn normalisation(&self, sets: &[ContextSet], range: Option<&JointRange>) -> Normalisation {
        let (state_mean, state_std) = match range {
            Some(range) => {
                let unbounded: Vec<Vec<f64>> = self
                    .rows()
                    .map(|(y, _)| (0..y.len()).map(|i| range.unbounded(i, y[i])).collect())
                    .collect();
                moments(unbounded.iter().map(Vec::as_slice))
            }
            None => moments(self.rows().map(|(y, _)| y)),
        };
        let (mut context_mean, mut context_std) = moments(self.rows().map(|(_, c)| c));
        for set in sets {
            pool_slots(set, &mut context_mean, &mut context_std);
        }
        Normalisation {
            state_mean,
            state_std,
            context_mean,
            context_std,
        }
    }

    /// The bounding box of the fitted episodes' states and contexts.
    pub fn bounds(&self) -> Bounds {
        let (state_min, state_max) = extent(self.rows().map(|(y, _)| y));
        let (context_min, context_max) = extent(self.rows().map(|(_, c)| c));
        Bounds {
            state_min,
            state_max,
            context_min,
            context_max,
        }
    }
}

fn moments<'a>(rows: impl Iterator<Item = &'a [f64]> + Clone) -> (Vec<f64>, Vec<f64>) {
    let n = rows.clone().count() as f64;
    let dim = rows.clone().next().map_or(0, <[f64]>::len);
    let mut mean = vec![0.0; dim];
    for r in rows.clone() {
        for (m, v) in mean.iter_mut().zip(r) {
            *m += v / n;
        }
    }
    let mut var = vec![0.0; dim];
    for r in rows {
        for ((s, v), m) in var.iter_mut().zip(r).zip(&mean) {
            *s += (v - m) * (v - m) / n;
        }
    }
    (
        mean,
        var.into_iter().map(|v| v.sqrt().max(MIN_STD)).collect(),
    )
}

/// Replaces each slot's `(mean, std)` of `set` by those of all its elements together:
/// the slots hold equally many rows, so the pooled mean is the slots' mean and the pooled
/// variance the mean of `σ² + (μ_slot - μ)²`.
fn pool_slots(set: &ContextSet, mean: &mut [f64], std: &mut [f64]) {
    let n = set.count as f64;
    for i in 0..set.size {
        let slots = (0..set.count).map(|j| set.start + j * set.size + i);
        let pooled_mean = slots.clone().map(|k| mean[k]).sum::<f64>() / n;
        let variance = slots
            .clone()
            .map(|k| std[k].powi(2) + (mean[k] - pooled_mean).powi(2))
            .sum::<f64>()
            / n;
        for k in slots {
            mean[k] = pooled_mean;
            std[k] = variance.sqrt();
        }
    }
}

fn extent<'a>(rows: impl Iterator<Item = &'a [f64]>) -> (Vec<f64>, Vec<f64>) {
    let mut lo: Vec<f64> = Vec::new();
    let mut hi: Vec<f64> = Vec::new();
    for r in rows {
        if lo.is_empty() {
            lo = r.to_vec();
            hi = r.to_vec();
        }
        for ((l, h), v) in lo.iter_mut().zip(hi.iter_mut()).zip(r) {
            *l = l.min(*v);
            *h = h.max(*v);
        }
    }
    (lo, hi)
}

/// Transitions `(y_t → y_{t+k} | c_t)`, row `i` over `k = steps[i]` steps of `dt`.
#[derive(Debug)]
pub struct Pairs {
    pub prev: Tensor,
    pub next: Tensor,
    pub context: Tensor,
    pub steps: Tensor,
}

/// The demonstrations as tensors: every state `y_t` with its context `c_t`, the rows that
/// start a transition, and each episode's first state.
///
/// Transition row `i` starts at state `starts[i] = t` and may span `k ∈ 1..=room[i]`
/// steps (to `y_{t+k}`, within its episode and short of its next excluded transition);
/// [`draw`](Self::draw) gathers a batch of rows with random spans. Excluded transitions
/// start no row.
#[derive(Debug)]
pub struct Transitions {
    states: Tensor,
    contexts: Tensor,
    starts: Tensor,
    room: Tensor,
    pub initial: Tensor,
    pub initial_context: Tensor,
    /// The most steps of any episode.
    longest: usize,
}

fn matrix(rows: &[&[f64]], cols: usize) -> Tensor {
    let flat: Vec<f64> = rows.iter().flat_map(|r| r.iter().copied()).collect();
    Tensor::from_slice(&flat)
        .to_kind(Kind::Double)
        .reshape([rows.len() as i64, cols as i64])
}

/// `k ~ U{1, …, span}` per entry of `spans`.
fn uniform_steps(spans: &Tensor) -> Tensor {
    let spans = spans.to_kind(Kind::Double);
    (spans.rand_like() * spans).floor().to_kind(Kind::Int64) + 1
}

impl Transitions {
    pub fn new(episodes: &[&Episode], d: usize, m: usize) -> Self {
        let (mut states, mut contexts) = (Vec::new(), Vec::new());
        let (mut starts, mut room) = (Vec::new(), Vec::new());
        for e in episodes {
            let offset = states.len() as i64;
            for t in 0..e.states.len() {
                states.push(e.states[t].as_slice());
                contexts.push(e.context(t));
            }
            for (t, run) in e.counted_runs().into_iter().enumerate() {
                if run > 0 {
                    starts.push(offset + t as i64);
                    room.push(run);
                }
            }
        }
        let initial: Vec<&[f64]> = episodes.iter().map(|e| e.states[0].as_slice()).collect();
        let initial_context: Vec<&[f64]> = episodes.iter().map(|e| e.context(0)).collect();
        Self {
            states: matrix(&states, d),
            contexts: matrix(&contexts, m),
            starts: Tensor::from_slice(&starts),
            room: Tensor::from_slice(&room),
            initial: matrix(&initial, d),
            initial_context: matrix(&initial_context, m),
            longest: episodes
                .iter()
                .map(|e| e.states.len() - 1)
                .max()
                .unwrap_or(0),
        }
    }

    /// Number of transition rows (states that have a successor).
    pub fn len(&self) -> usize {
        self.starts.size()[0] as usize
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    pub fn episodes(&self) -> usize {
        self.initial.size()[0] as usize
    }

    /// The most steps of any episode: the longest span [`draw`](Self::draw) can return.
    pub fn longest(&self) -> usize {
        self.longest
    }

    /// The transitions of `rows`: with probability `arrival` a row spans every step left
    /// in its episode (`y_t → y_T`, where and when the motion ends; or up to the next
    /// excluded transition), otherwise
    /// `k ~ U{1, …, min(max_steps, room)}` steps, `room` the steps left. Drawn within the
    /// room rather than clamped to it: clamping would pile the late rows' spans onto each
    /// episode's last state.
    pub fn draw(&self, rows: &Tensor, max_steps: usize, arrival: f64) -> Pairs {
        let room = self.room.index_select(0, rows);
        let mut steps = match max_steps {
            1 => rows.ones_like(),
            _ => uniform_steps(&room.clamp_max(max_steps as i64)),
        };
        if arrival > 0.0 {
            let to_end = room.to_kind(Kind::Double).rand_like().lt(arrival);
            steps = room.where_self(&to_end, &steps);
        }
        self.gather(&self.starts.index_select(0, rows), steps)
    }

    /// Every one-step transition.
    pub fn one_step(&self) -> Pairs {
        let rows = Tensor::arange(self.len() as i64, tch::kind::INT64_CPU);
        self.draw(&rows, 1, 0.0)
    }

    /// The pairs `(y_s → y_{s+k} | c_s)` for state rows `s` and spans `k`.
    fn gather(&self, start: &Tensor, steps: Tensor) -> Pairs {
        Pairs {
            prev: self.states.index_select(0, start),
            next: self.states.index_select(0, &(start + &steps)),
            context: self.contexts.index_select(0, start),
            steps,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// One episode of 1-D states `y_t = t`, so a pair's states name its indices.
    fn counting_episode(steps: usize, excluded: &[usize]) -> Episode {
        Episode {
            seed: None,
            states: (0..=steps).map(|t| vec![t as f64]).collect(),
            contexts: Contexts::PerEpisode(vec![]),
            excluded: (0..steps).map(|t| excluded.contains(&t)).collect(),
        }
    }

    fn indices(tensor: &Tensor) -> Vec<i64> {
        Vec::<f64>::try_from(tensor.flatten(0, -1))
            .unwrap()
            .into_iter()
            .map(|v| v as i64)
            .collect()
    }

    #[test]
    fn no_modelled_span_crosses_an_excluded_transition() {
        let (steps, excluded) = (30, [4, 5, 17]);
        let episode = counting_episode(steps, &excluded);
        let transitions = Transitions::new(&[&episode], 1, 0);
        assert_eq!(transitions.len(), steps - excluded.len());
        let one_step = transitions.one_step();
        let starts = indices(&one_step.prev);
        assert!(
            excluded.iter().all(|&t| !starts.contains(&(t as i64))),
            "{starts:?}"
        );
        tch::manual_seed(3);
        let rows = Tensor::arange(transitions.len() as i64, tch::kind::INT64_CPU).repeat([200]);
        let pairs = transitions.draw(&rows, steps, 0.3);
        let (prev, next) = (indices(&pairs.prev), indices(&pairs.next));
        let longest = prev.iter().zip(&next).map(|(p, n)| n - p).max().unwrap();
        assert!(longest > 5, "long spans were drawn ({longest})");
        for (p, n) in prev.iter().zip(&next) {
            assert!(
                excluded.iter().all(|&x| !(*p..*n).contains(&(x as i64))),
                "{p} → {n} crosses an excluded transition"
            );
        }
    }

    #[test]
    fn exclusion_flags_must_match_the_transitions_and_leave_some() {
        let data = |episode: Episode| Demonstrations {
            episodes: vec![episode],
            dt: 0.1,
        };
        let mut short = counting_episode(5, &[]);
        short.excluded.pop();
        assert!(matches!(
            data(short).validate(),
            Err(TrainError::InvalidData(_))
        ));
        let all = counting_episode(5, &[0, 1, 2, 3, 4]);
        assert!(matches!(
            data(all).validate(),
            Err(TrainError::InvalidData(_))
        ));
        assert!(data(counting_episode(5, &[2])).validate().is_ok());
    }
}
