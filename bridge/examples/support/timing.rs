//! Latency sampling shared by the round-trip example and the sessions benchmark.

use std::time::{Duration, Instant};

/// Median and p99 of `samples` timed calls of `call`, after `warmup` untimed ones.
pub fn time_calls(warmup: usize, samples: usize, mut call: impl FnMut()) -> (Duration, Duration) {
    for _ in 0..warmup {
        call();
    }
    let mut timed: Vec<Duration> = (0..samples)
        .map(|_| {
            let start = Instant::now();
            call();
            start.elapsed()
        })
        .collect();
    timed.sort();
    let at = |p: f64| timed[((timed.len() - 1) as f64 * p).round() as usize];
    (at(0.5), at(0.99))
}

pub fn micros(d: Duration) -> f64 {
    d.as_secs_f64() * 1e6
}
