//! The driver of a policy-driven session (`run`): a thread that steps the environment
//! with the policy's action once per control period of simulated time, paced so that
//! simulated time advances at `speed` × wall-clock time (as fast as possible for 0).
//!
//! The session's lock is taken for one step at a time, so `perturb`, `context`, `render`
//! and `stop` requests are served between steps and act from the next one on. The policy
//! is looked up by name at every step: a hot-loaded checkpoint takes over at the next
//! step. The driver ends when the episode ends, after the requested steps, on `stop`, or
//! when the session is closed or reclaimed (it holds only a weak reference to it).

use std::sync::{Mutex, Weak};
use std::time::{Duration, Instant};

use super::policy_table::PolicyTable;
use super::session::{Run, Session};

pub(crate) struct Driver {
    pub session: Weak<Mutex<Session>>,
    pub policies: std::sync::Arc<PolicyTable>,
    pub run: Run,
    pub speed: f64,
    pub steps: Option<u32>,
    pub control_dt: f64,
    pub action_dim: usize,
}

impl Driver {
    pub fn spawn(self) -> std::io::Result<()> {
        std::thread::Builder::new()
            .name(format!("ciflow-run-{}", self.run.policy))
            .spawn(move || self.drive())
            .map(|_| ())
    }

    fn drive(self) {
        let started = Instant::now();
        let mut action = vec![0.0; self.action_dim];
        let mut taken: u32 = 0;
        loop {
            taken = taken.saturating_add(1);
            if !self.step(&mut action, self.steps.is_some_and(|steps| taken >= steps)) {
                return;
            }
            if self.speed > 0.0 {
                let due = Duration::from_secs_f64(f64::from(taken) * self.control_dt / self.speed);
                if let Some(wait) = due.checked_sub(started.elapsed()) {
                    std::thread::sleep(wait);
                }
            }
        }
    }

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
