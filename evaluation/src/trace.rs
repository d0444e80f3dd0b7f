//! One episode's per-step record, as the closed-loop evaluation keeps it and pushes
//! measure it.

use ciflow_envs::env::Info;
use serde::{Deserialize, Serialize};

/// `info` keys of a tool point in the world, reported by pouring (the cup's spout).
pub const TOOL_POINT_KEYS: [&str; 3] = ["spout_x", "spout_y", "spout_z"];

/// One episode's per-step record: `T + 1` states (the reset one first), `T` commands.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Trace {
    /// Simulated time of each state, s.
    pub time: Vec<f64>,
    pub q: Vec<Vec<f64>>,
    pub qd: Vec<Vec<f64>>,
    /// `command[k]`: the clipped `q̈_des` applied from state `k`.
    pub command: Vec<Vec<f64>>,
    pub context: Vec<Vec<f64>>,
    /// The tool point where the task reports one ([`TOOL_POINT_KEYS`]: pouring's spout,
    /// m), else the position `q` itself: the point whose displacement and path pushes
    /// measure.
    pub point: Vec<Vec<f64>>,
}

impl Trace {
    pub(crate) fn record(&mut self, observation: &[f64], state_dim: usize, info: &Info) {
        let (q, rest) = observation.split_at(state_dim);
        let (qd, context) = rest.split_at(state_dim);
        self.time
            .push(info.get("time").copied().unwrap_or(f64::NAN));
        self.q.push(q.to_vec());
        self.qd.push(qd.to_vec());
        self.context.push(context.to_vec());
        let tool: Option<Vec<f64>> = TOOL_POINT_KEYS
            .iter()
            .map(|k| info.get(k).copied())
            .collect();
        self.point.push(tool.unwrap_or_else(|| q.to_vec()));
    }

    /// The tracked point at time `t` (the last one after the trace ends).
    pub(crate) fn point_at(&self, t: f64) -> &[f64] {
        let k = self.time.partition_point(|&s| s < t - 1e-9);
        &self.point[k.min(self.point.len() - 1)]
    }
}
