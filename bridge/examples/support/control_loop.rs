//! A fixed-rate control loop as a robot's controller runs it, shared by the two
//! `control_loop*` examples: the policy is asked for `q̈_des` once per period, the answer
//! drives a stand-in plant (a double integrator `q̈ = a`, the joint-space behaviour of a
//! computed-torque arm), and every call's latency and every missed deadline is counted.

use std::time::{Duration, Instant};

use ciflow_envs::env::EnvSpec;

/// 1 kHz, the rate of a Franka or UR joint-torque loop.
pub const PERIOD: Duration = Duration::from_millis(1);
/// Sleep until this long before a deadline, then spin: `sleep` overshoots by tens of µs.
const SPIN: Duration = Duration::from_micros(100);

/// The state the external loop owns: `q`, `q̇` and the context, observed as `[q, q̇, c]`.
pub struct Plant {
    q: Vec<f64>,
    qd: Vec<f64>,
    context: Vec<f64>,
    observation: Vec<f64>,
}

impl Plant {
    /// At rest in the middle of the task's position range and context box (0 where a
    /// range is unbounded), observed as `observation_dim` numbers: a policy of the task
    /// built with other arguments (e.g. fewer obstacles) gets a zero context.
    pub fn at_rest(spec: &EnvSpec, observation_dim: usize) -> Self {
        let middle = |low: &f64, high: &f64| {
            let m = (low + high) / 2.0;
            if m.is_finite() { m } else { 0.0 }
        };
        let d = spec.action_space.dim();
        let observation = &spec.observation_space;
        let q = observation.low[..d]
            .iter()
            .zip(&observation.high[..d])
            .map(|(l, h)| middle(l, h))
            .collect();
        let context_dim = observation_dim.saturating_sub(2 * d);
        let context_box = &spec.context_space;
        let context = if context_box.dim() == context_dim {
            context_box
                .low
                .iter()
                .zip(&context_box.high)
                .map(|(l, h)| middle(l, h))
                .collect()
        } else {
            vec![0.0; context_dim]
        };
        Self {
            q,
            qd: vec![0.0; d],
            context,
            observation: Vec::with_capacity(observation_dim),
        }
    }

    pub fn observation(&mut self) -> &[f64] {
        self.observation.clear();
        self.observation.extend_from_slice(&self.q);
        self.observation.extend_from_slice(&self.qd);
        self.observation.extend_from_slice(&self.context);
        &self.observation
    }

    /// One period of `q̈ = acceleration` (semi-implicit Euler).
    pub fn advance(&mut self, acceleration: &[f64], dt: f64) {
        for ((q, qd), a) in self.q.iter_mut().zip(&mut self.qd).zip(acceleration) {
            *qd += a * dt;
            *q += *qd * dt;
        }
    }

    pub fn velocity_norm(&self) -> f64 {
        self.qd.iter().map(|v| v * v).sum::<f64>().sqrt()
    }
}

/// What one run of the loop measured.
pub struct LoopReport {
    /// The latency of every call, sorted.
    latencies: Vec<Duration>,
    /// Periods whose answer came after their deadline, or that were skipped because an
    /// earlier answer came later still.
    misses: usize,
    periods: usize,
}

impl LoopReport {
    fn quantile(&self, p: f64) -> Duration {
        self.latencies[((self.latencies.len() - 1) as f64 * p).round() as usize]
    }

    pub fn median(&self) -> Duration {
        self.quantile(0.5)
    }

    pub fn p99(&self) -> Duration {
        self.quantile(0.99)
    }

    /// One line: calls, median, p99, max latency and deadline misses.
    pub fn summary(&self, what: &str) -> String {
        let us = |d: Duration| d.as_secs_f64() * 1e6;
        format!(
            "{what}: {} calls, median {:.1} us, p99 {:.1} us, max {:.1} us, \
             missed {} of {} deadlines ({:.3} %)",
            self.latencies.len(),
            us(self.median()),
            us(self.p99()),
            us(*self.latencies.last().expect("at least one call")),
            self.misses,
            self.periods,
            100.0 * self.misses as f64 / self.periods as f64,
        )
    }
}

/// Calls `tick` once per [`PERIOD`] for `duration`; a period's deadline is its end.
pub fn run_at_1khz<E>(
    duration: Duration,
    mut tick: impl FnMut() -> Result<(), E>,
) -> Result<LoopReport, E> {
    let start = Instant::now();
    let periods_total = (duration.as_nanos() / PERIOD.as_nanos()).max(1) as usize;
    let mut latencies = Vec::with_capacity(periods_total);
    let (mut misses, mut period) = (0, 0);
    while period < periods_total {
        let deadline = start + PERIOD * (period as u32 + 1);
        let called = Instant::now();
        tick()?;
        let answered = Instant::now();
        latencies.push(answered - called);
        period += 1;
        if answered > deadline {
            // This period is missed, and so is every one the late answer ran into.
            let late = (answered - deadline).as_nanos() / PERIOD.as_nanos();
            let skipped = (late as usize).min(periods_total - period);
            misses += 1 + skipped;
            period += skipped;
            continue;
        }
        if let Some(rest) = deadline.checked_duration_since(Instant::now() + SPIN) {
            std::thread::sleep(rest);
        }
        while Instant::now() < deadline {
            std::hint::spin_loop();
        }
    }
    latencies.sort();
    Ok(LoopReport {
        latencies,
        misses,
        periods: periods_total,
    })
}

/// `--seconds S` from the arguments after the positional ones (default 60).
pub fn seconds(args: &[String]) -> Result<Duration, String> {
    match args {
        [] => Ok(Duration::from_secs(60)),
        [flag, value] if flag == "--seconds" => value
            .parse::<f64>()
            .ok()
            .filter(|s| s.is_finite() && *s > 0.0)
            .map(Duration::from_secs_f64)
            .ok_or_else(|| format!("--seconds {value}: a positive number of seconds is needed")),
        other => Err(format!("unexpected arguments {other:?}")),
    }
}
