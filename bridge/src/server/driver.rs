//! The drivers of policy-driven sessions (`run`): each steps its environment with the
//! policy's action once per control period of simulated time, paced so that simulated
//! time advances at `speed` × wall-clock time (as fast as possible for 0).
//!
//! Runs do not own threads. A few scheduler threads (one per core) each keep a queue of
//! drivers ordered by when their next step is due, take the earliest, step it and queue it
//! again, and sleep until the next due step or a new run arrives; a thousand runs cost a
//! thousand queue entries, not a thousand stacks.
//!
//! The session's lock is taken for one step at a time, so `perturb`, `context`, `render`
//! and `stop` requests are served between steps and act from the next one on. The policy
//! is looked up by name at every step: a hot-loaded checkpoint takes over at the next
//! step. A driver ends when the episode ends, after the requested steps, on `stop`, or
//! when the session is closed or reclaimed (it holds only a weak reference to it).

use std::cmp::{Ordering as Order, Reverse};
use std::collections::BinaryHeap;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError, Sender};
use std::sync::{Arc, Mutex, Weak};
use std::thread;
use std::time::{Duration, Instant};

use super::policy_table::PolicyTable;
use super::session::{Run, Session};

pub(crate) struct Driver {
    pub session: Weak<Mutex<Session>>,
    pub policies: Arc<PolicyTable>,
    pub run: Run,
    pub speed: f64,
    pub steps: Option<u32>,
    pub control_dt: f64,
    pub action_dim: usize,
}

/// The scheduler threads; a run goes to the next one in turn.
pub(crate) struct Schedulers {
    queues: Vec<Sender<Driver>>,
    next: AtomicUsize,
}

impl Schedulers {
    /// Starts one scheduler per core; they end when this is dropped and their runs end.
    pub fn spawn(name: &str) -> std::io::Result<Self> {
        let count = thread::available_parallelism().map_or(2, |n| n.get());
        let queues = (0..count)
            .map(|index| {
                let (queue, arrivals) = mpsc::channel();
                thread::Builder::new()
                    .name(format!("ciflow-runs-{name}-{index}"))
                    .spawn(move || schedule(&arrivals))
                    .map(|_| queue)
            })
            .collect::<std::io::Result<_>>()?;
        Ok(Self {
            queues,
            next: AtomicUsize::new(0),
        })
    }

    /// Starts stepping `driver` now; gives it back if its scheduler is gone.
    pub fn start(&self, driver: Driver) -> Result<(), Driver> {
        let index = self.next.fetch_add(1, Ordering::Relaxed) % self.queues.len();
        self.queues[index].send(driver).map_err(|error| error.0)
    }
}

/// A driver waiting for its next step, ordered by when it is due (then by arrival).
struct Pending {
    due: Instant,
    order: u64,
    driver: Driver,
    started: Instant,
    taken: u32,
    action: Vec<f64>,
}

impl PartialEq for Pending {
    fn eq(&self, other: &Self) -> bool {
        (self.due, self.order) == (other.due, other.order)
    }
}

impl Eq for Pending {}

impl PartialOrd for Pending {
    fn partial_cmp(&self, other: &Self) -> Option<Order> {
        Some(self.cmp(other))
    }
}

impl Ord for Pending {
    fn cmp(&self, other: &Self) -> Order {
        (self.due, self.order).cmp(&(other.due, other.order))
    }
}

/// One scheduler thread: steps whichever driver is due first, until no driver is left
/// and nobody can send another.
fn schedule(arrivals: &Receiver<Driver>) {
    let mut queue = BinaryHeap::<Reverse<Pending>>::new();
    let mut order = 0u64;
    loop {
        let wait = queue
            .peek()
            .map(|Reverse(next)| next.due.saturating_duration_since(Instant::now()));
        let arrival = match wait {
            Some(wait) => arrivals.recv_timeout(wait),
            None => arrivals.recv().map_err(|_| RecvTimeoutError::Disconnected),
        };
        match arrival {
            Ok(driver) => {
                order += 1;
                let now = Instant::now();
                let action = vec![0.0; driver.action_dim];
                queue.push(Reverse(Pending {
                    due: now,
                    order,
                    driver,
                    started: now,
                    taken: 0,
                    action,
                }));
            }
            Err(RecvTimeoutError::Timeout) => {}
            // The engine is gone: finish the runs still queued (their sessions are gone
            // too, so each ends at its next step), sleeping rather than spinning.
            Err(RecvTimeoutError::Disconnected) => match wait {
                None => return,
                Some(wait) => thread::sleep(wait),
            },
        }
        let now = Instant::now();
        while queue.peek().is_some_and(|Reverse(next)| next.due <= now) {
            let Reverse(mut pending) = queue.pop().expect("peeked");
            pending.taken = pending.taken.saturating_add(1);
            let driver = &pending.driver;
            let last = driver.steps.is_some_and(|steps| pending.taken >= steps);
            if !driver.step(&mut pending.action, last) {
                continue;
            }
            pending.due = if driver.speed > 0.0 {
                let since_start = f64::from(pending.taken) * driver.control_dt / driver.speed;
                pending.started + Duration::from_secs_f64(since_start)
            } else {
                // As fast as possible, but after everything already due: an instant past
                // this pass's puts it behind them and lets new runs in before its next step.
                Instant::now().max(now + Duration::from_nanos(1))
            };
            order += 1;
            pending.order = order;
            queue.push(Reverse(pending));
        }
    }
}

impl Driver {
    /// One step under the session's lock; whether the run goes on.
    fn step(&self, action: &mut [f64], last: bool) -> bool {
        let Some(session) = self.session.upgrade() else {
            return false;
        };
        let Ok(mut session) = session.lock() else {
            return false;
        };
        if !session.is_running(&self.run) {
            return false;
        }
        match self.policies.get(&self.run.policy) {
            Some(policy) => matches!(
                session.drive(&self.run, policy.as_ref(), action, last),
                Ok(true)
            ),
            // Policies are replaced, never removed; should that change, stop cleanly.
            None => {
                let _ = session.stop_run();
                false
            }
        }
    }
}
