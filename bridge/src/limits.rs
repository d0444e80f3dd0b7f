//! What one engine accepts: bounds per request, per session and per client.
//!
//! Every bound is refused with the typed error `limit_exceeded` before anything is
//! allocated, and every request is answered within a time budget (`deadline_exceeded`
//! otherwise, again leaving nothing behind). Clients read the bounds, and their own usage,
//! with the `limits` operation.

use std::time::{Duration, Instant};

use serde::{Deserialize, Serialize};

use crate::error::BridgeError;
use crate::protocol::MAX_REQUEST_BYTES;

/// Bounds an engine enforces. The defaults keep one client's environments under about
/// 2.3 GB for the heaviest task (a reset Panda pouring environment takes about 17 kB) and
/// answer every request well inside Zenoh's default 10 s query timeout.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct Limits {
    /// Most environments in one session.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = Limits::DEFAULT.max_envs_per_session))]
    pub max_envs_per_session: u32,
    /// Most environments one client holds over all of its sessions (what bounds its
    /// memory).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = Limits::DEFAULT.max_envs_per_client))]
    pub max_envs_per_client: u32,
    /// Most sessions one client holds at once.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = Limits::DEFAULT.max_sessions_per_client))]
    pub max_sessions_per_client: u32,
    /// Most policy runs (`run`) driving sessions at once, over all clients.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = Limits::DEFAULT.max_runs))]
    pub max_runs: u32,
    /// Largest request payload, in bytes (at most the protocol's 64 MiB).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = Limits::DEFAULT.max_request_bytes))]
    pub max_request_bytes: u32,
    /// Most observations in one `act` request.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = Limits::DEFAULT.max_act_observations))]
    pub max_act_observations: u32,
    /// Longest the engine works on one request, in milliseconds, queueing included; a
    /// request may ask for less with `deadline_ms`. Half of Zenoh's default query timeout,
    /// so the client hears the refusal before it stops listening.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = Limits::DEFAULT.request_budget_ms))]
    pub request_budget_ms: u32,
}

impl Limits {
    pub const DEFAULT: Limits = Limits {
        max_envs_per_session: 65_536,
        max_envs_per_client: 131_072,
        max_sessions_per_client: 1_024,
        max_runs: 1_024,
        max_request_bytes: MAX_REQUEST_BYTES as u32,
        max_act_observations: 65_536,
        request_budget_ms: 5_000,
    };

    /// Refuses a zero bound: it would refuse every request of its kind.
    pub fn check(&self) -> Result<(), BridgeError> {
        let bounds = [
            ("max_envs_per_session", self.max_envs_per_session),
            ("max_envs_per_client", self.max_envs_per_client),
            ("max_sessions_per_client", self.max_sessions_per_client),
            ("max_runs", self.max_runs),
            ("max_request_bytes", self.max_request_bytes),
            ("max_act_observations", self.max_act_observations),
            ("request_budget_ms", self.request_budget_ms),
        ];
        if let Some((name, _)) = bounds.iter().find(|(_, bound)| *bound == 0) {
            return Err(BridgeError::InvalidArgument(format!(
                "limit {name} is 0, which would refuse every request it bounds"
            )));
        }
        if self.max_request_bytes as usize > MAX_REQUEST_BYTES {
            return Err(BridgeError::InvalidArgument(format!(
                "limit max_request_bytes {} exceeds the protocol's {MAX_REQUEST_BYTES}",
                self.max_request_bytes
            )));
        }
        Ok(())
    }

    /// When a request received at `received` that asked for `deadline_ms` must be
    /// answered by.
    pub(crate) fn deadline(&self, received: Instant, deadline_ms: Option<u32>) -> Deadline {
        let budget =
            deadline_ms.map_or(self.request_budget_ms, |ms| ms.min(self.request_budget_ms));
        Deadline(received + Duration::from_millis(u64::from(budget)))
    }
}

impl Default for Limits {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// The instant by which a request must be answered.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Deadline(Instant);

impl Deadline {
    pub fn passed(&self) -> bool {
        Instant::now() >= self.0
    }
}

/// What one client holds, as the `limits` operation reports it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Usage {
    pub sessions: u32,
    pub envs: u64,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_zero_bound_is_refused_and_a_deadline_is_the_smaller_budget() {
        assert!(Limits::DEFAULT.check().is_ok());
        let no_runs = Limits {
            max_runs: 0,
            ..Limits::DEFAULT
        };
        assert!(
            no_runs
                .check()
                .unwrap_err()
                .to_string()
                .contains("max_runs")
        );

        let received = Instant::now();
        let budget = Duration::from_millis(u64::from(Limits::DEFAULT.request_budget_ms));
        let asked = Limits::DEFAULT.deadline(received, Some(100));
        assert_eq!(asked.0, received + Duration::from_millis(100));
        let greedy = Limits::DEFAULT.deadline(received, Some(u32::MAX));
        assert_eq!(greedy.0, received + budget);
        assert_eq!(
            Limits::DEFAULT.deadline(received, None).0,
            received + budget
        );
    }
}
