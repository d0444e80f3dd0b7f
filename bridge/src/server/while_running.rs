//! The engine's state for threads that may outlive the engine itself.
//!
//! A thread that confirms a client has vanished (`ciflow-vanished`) runs for up to a second
//! and holds no reference to the engine while it waits. Upgrading a weak reference for
//! each look is not enough: if the engine is dropped during a look, that thread holds the
//! last reference, and the engine's Zenoh session closes on it, after the drop returned —
//! at a program's exit, after Zenoh's statics were gone. [`WhileRunning::stop`] waits for
//! the uses in progress and refuses the rest, so after it no such thread holds the state.

use std::sync::{Arc, RwLock, Weak};

pub(crate) struct WhileRunning<T> {
    /// `true` once stopped; held for reading through each use of the state.
    stopped: RwLock<bool>,
    state: Weak<T>,
}

impl<T> WhileRunning<T> {
    pub fn new(state: &Arc<T>) -> Self {
        Self {
            stopped: RwLock::new(false),
            state: Arc::downgrade(state),
        }
    }

    /// `use_state` on the state, unless [`stop`](Self::stop) was called or the state is
    /// gone.
    pub fn with<R>(&self, use_state: impl FnOnce(&T) -> R) -> Option<R> {
        let stopped = self.stopped.read().unwrap_or_else(|p| p.into_inner());
        if *stopped {
            return None;
        }
        let state = self.state.upgrade()?;
        let result = use_state(&state);
        // Before the lock: once `stop` has it, no reference taken here is left.
        drop(state);
        drop(stopped);
        Some(result)
    }

    /// Waits for the uses in progress to end; every later [`with`](Self::with) gets `None`.
    pub fn stop(&self) {
        *self.stopped.write().unwrap_or_else(|p| p.into_inner()) = true;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicBool, Ordering};
    use std::sync::mpsc;
    use std::thread;
    use std::time::Duration;

    #[test]
    fn the_state_is_lent_until_stopped() {
        let state = Arc::new(7);
        let running = WhileRunning::new(&state);
        assert_eq!(running.with(|value| value + 1), Some(8));
        running.stop();
        assert_eq!(running.with(|value| value + 1), None);
        assert_eq!(Arc::strong_count(&state), 1);
    }

    #[test]
    fn a_state_already_gone_is_not_lent() {
        let state = Arc::new(7);
        let running = WhileRunning::new(&state);
        drop(state);
        assert_eq!(running.with(|value| value + 1), None);
    }

    #[test]
    fn stop_returns_only_once_the_use_in_progress_let_go_of_the_state() {
        let state = Arc::new(AtomicBool::new(false));
        let running = Arc::new(WhileRunning::new(&state));
        let (entered, in_use) = mpsc::channel();
        let user = {
            let running = Arc::clone(&running);
            thread::spawn(move || {
                running.with(|finished| {
                    entered.send(()).unwrap();
                    thread::sleep(Duration::from_millis(200));
                    finished.store(true, Ordering::SeqCst);
                })
            })
        };
        in_use.recv().unwrap();
        running.stop();
        assert!(state.load(Ordering::SeqCst), "stop returned during a use");
        assert_eq!(
            Arc::strong_count(&state),
            1,
            "a thread still held the state after stop"
        );
        assert_eq!(user.join().unwrap(), Some(()));
    }
}
