//! Asking again for a moment. Zenoh's routes take a moment to settle after a declaration
//! or a reconnection, and until they do a query can come back empty although what it asks
//! for exists (eclipse-zenoh/zenoh#2767). The client and the engine both repeat such an
//! empty answer briefly before believing it.

use std::time::{Duration, Instant};

/// Runs `attempt` until `again` rejects its outcome or `window` would be over after the
/// next pause, pausing 10, 20, 40 … ms in between; returns the last outcome.
pub(crate) fn retry_within<T>(
    window: Duration,
    mut attempt: impl FnMut() -> T,
    again: impl Fn(&T) -> bool,
) -> T {
    let give_up = Instant::now() + window;
    let mut pause = Duration::from_millis(10);
    loop {
        let outcome = attempt();
        if !again(&outcome) || Instant::now() + pause >= give_up {
            return outcome;
        }
        std::thread::sleep(pause);
        pause *= 2;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_outcome_that_needs_no_retry_ends_it_and_the_window_bounds_the_rest() {
        let mut attempts = 0;
        let outcome = retry_within(
            Duration::from_secs(10),
            || {
                attempts += 1;
                attempts
            },
            |&n| n < 3,
        );
        assert_eq!(outcome, 3, "stops at the first outcome not asked again");

        let started = Instant::now();
        let mut attempts = 0;
        retry_within(Duration::from_millis(200), || attempts += 1, |_| true);
        let waited = started.elapsed();
        // Pauses of 10 + 20 + 40 ms fit in the window, the next 80 ms would not.
        assert!(attempts >= 3, "{attempts} attempts");
        assert!(
            waited < Duration::from_millis(200),
            "gave up after {waited:?}"
        );
    }
}
