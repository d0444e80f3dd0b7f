//! What a session's `step_batch` replies have told its client of the environments'
//! contexts, so that a reply carries only the contexts that changed.
//!
//! A context is part of every observation, yet it changes only at a reset, an autoreset,
//! a `context` request or by the task itself: of the 12 values of a 3-obstacle
//! observation, 8 are its context, and re-sending them at every step was nearly half of a
//! 4 096-environment reply (0.54 MiB, 0.29 without them). Each step compares every environment's context with the one
//! last reported (a comparison catches a change whatever made it) and stamps a change
//! with the epoch of the reply that first reports it. The client names the epoch of the
//! last reply it applied, so the reply sends every context changed after it: a reply that
//! never arrived is made up by the next one.
//!
//! A reply is written into a buffer sized before the step, so [`room`](ReportedContexts::room)
//! says how many contexts the update will hold, from what the engine knows before
//! stepping: those stamped in replies the client did not apply, those that requests
//! changed (a batch reset, a `context` request, a step whose reply was whole and so
//! reported no update for its autoresets) and those of the environments that autoreset at
//! this step. Room for every context at every step took 0.28 MiB per 4 096
//! obstacle environments of Zenoh's 16 MiB shared-memory pool for nothing once the first
//! step had sent them. A change it cannot foresee (a task that changes its own context)
//! outgrows the room, and the reply moves to the heap: one copy, correct all the same.

use std::ops::Range;

use crate::protocol::{ContextUpdate, ErrorCode, ErrorReply, F64s, context_update_max_len};

/// Replies a client may have missed for [`ReportedContexts::room`] to count what it
/// missed; past them, it makes room for every context.
const RECENT_REPLIES: usize = 16;

pub(crate) struct ReportedContexts {
    context_dim: usize,
    /// Row-major `num_envs × context_dim`: each environment's context as last reported
    /// (NaN before the first report, which no context equals).
    values: Vec<f64>,
    /// Per environment, the epoch of the reply that first reported its context (1 before
    /// any reply: every context is new to a client that holds none, a task without
    /// context included).
    changed_at: Vec<u64>,
    /// The epoch of the last reply (0: none yet).
    epoch: u64,
    /// How many contexts each of the last replies stamped, by epoch modulo their count.
    stamped: [usize; RECENT_REPLIES],
    /// How many contexts requests changed since the last reply (an estimate from above:
    /// one environment's context set twice counts twice).
    requested: usize,
}

/// The reported contexts of a block of environments, for the task that steps them.
pub(crate) struct ReportedBlock<'a> {
    context_dim: usize,
    values: &'a mut [f64],
    changed_at: &'a mut [u64],
    /// The epoch of the reply being written.
    epoch: u64,
}

impl ReportedContexts {
    pub fn new(num_envs: usize, context_dim: usize) -> Self {
        Self {
            context_dim,
            values: vec![f64::NAN; num_envs * context_dim],
            changed_at: vec![1; num_envs],
            epoch: 0,
            stamped: [0; RECENT_REPLIES],
            requested: 0,
        }
    }

    /// A request changed (or may have changed) the contexts of `envs` environments.
    pub fn requested(&mut self, envs: usize) {
        self.requested = self.requested.saturating_add(envs);
    }

    /// Bytes to reserve for the next update, its key included, to a client that holds
    /// epoch `known` when `autoresets` environments autoreset at this step: room for the
    /// contexts stamped after `known`, those [requested](Self::requested) and those of
    /// the autoresets; for every one if the client holds none or missed more replies than
    /// are counted.
    pub fn room(&self, known: u64, autoresets: usize) -> usize {
        let num_envs = self.changed_at.len();
        let missed = self.epoch.saturating_sub(known);
        let envs = if known == 0 || missed > RECENT_REPLIES as u64 {
            num_envs
        } else {
            let stamped: usize = (known + 1..=self.epoch)
                .map(|epoch| self.stamped[epoch as usize % RECENT_REPLIES])
                .sum();
            stamped
                .saturating_add(self.requested)
                .saturating_add(autoresets)
                .min(num_envs)
        };
        context_update_max_len(envs, self.context_dim)
    }

    /// Starts the reply to a client that holds the contexts of epoch `known`: blocks of
    /// `rows` environments (the last may be shorter) in which to [`note`](ReportedBlock::note)
    /// each environment's context after its step. A client cannot hold an epoch not yet
    /// sent.
    pub fn start(&mut self, known: u64, rows: usize) -> Result<Vec<ReportedBlock<'_>>, ErrorReply> {
        if known > self.epoch {
            return Err(ErrorReply::new(
                ErrorCode::InvalidRequest,
                format!(
                    "known_contexts {known}: this session's replies have reached epoch {}",
                    self.epoch
                ),
            ));
        }
        let (context_dim, epoch) = (self.context_dim, self.epoch + 1);
        let rows = rows.max(1);
        Ok(self
            .values
            .chunks_mut((rows * context_dim).max(1))
            // A task without context has no values to split: its blocks hold none.
            .chain(std::iter::repeat_with(|| &mut [][..]))
            .zip(self.changed_at.chunks_mut(rows))
            .map(|(values, changed_at)| ReportedBlock {
                context_dim,
                values,
                changed_at,
                epoch,
            })
            .collect())
    }

    /// Ends the reply [`start`](Self::start) began once its blocks noted every
    /// environment: the contexts changed after epoch `known`.
    pub fn finish(&mut self, known: u64) -> ContextUpdate {
        self.epoch += 1;
        let mut update = ContextUpdate {
            epoch: self.epoch,
            envs: Vec::new(),
            values: F64s(Vec::new()),
        };
        let mut stamped = 0;
        for (i, &changed_at) in self.changed_at.iter().enumerate() {
            stamped += usize::from(changed_at == self.epoch);
            if changed_at > known {
                update
                    .envs
                    .push(u32::try_from(i).expect("under 4 billion environments"));
                update.values.0.extend_from_slice(&self.values[self.row(i)]);
            }
        }
        self.stamped[self.epoch as usize % RECENT_REPLIES] = stamped;
        self.requested = 0;
        update
    }

    fn row(&self, i: usize) -> Range<usize> {
        i * self.context_dim..(i + 1) * self.context_dim
    }
}

impl ReportedBlock<'_> {
    /// Environment `i` of the block has context `context` after its step.
    pub fn note(&mut self, i: usize, context: &[f64]) {
        let reported = &mut self.values[i * self.context_dim..(i + 1) * self.context_dim];
        // Bit for bit: a context that changed by any amount is sent again.
        if reported
            .iter()
            .zip(context)
            .any(|(r, c)| r.to_bits() != c.to_bits())
        {
            reported.copy_from_slice(context);
            self.changed_at[i] = self.epoch;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::ReportedContexts;
    use crate::protocol::context_update_max_len;

    /// Steps `contexts` (one row per environment) through a reply to a client holding
    /// epoch `known`, in blocks of 2.
    fn reply(
        reported: &mut ReportedContexts,
        known: u64,
        contexts: &[[f64; 2]],
    ) -> (u64, Vec<u32>, Vec<f64>) {
        let mut blocks = reported.start(known, 2).unwrap();
        for (i, context) in contexts.iter().enumerate() {
            blocks[i / 2].note(i % 2, context);
        }
        drop(blocks);
        let update = reported.finish(known);
        (update.epoch, update.envs, update.values.0)
    }

    #[test]
    fn sends_every_context_first_then_only_changes() {
        let mut reported = ReportedContexts::new(3, 2);
        let mut contexts = [[1.0, 2.0], [3.0, 4.0], [5.0, 6.0]];
        let (epoch, envs, values) = reply(&mut reported, 0, &contexts);
        assert_eq!((epoch, envs), (1, vec![0, 1, 2]));
        assert_eq!(values, [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]);
        let (epoch, envs, values) = reply(&mut reported, 1, &contexts);
        assert_eq!((epoch, envs, values), (2, vec![], vec![]));
        contexts[2][1] = 6.5;
        let (epoch, envs, values) = reply(&mut reported, 2, &contexts);
        assert_eq!((epoch, envs, values), (3, vec![2], vec![5.0, 6.5]));
        // A context back to an earlier value is a change too.
        contexts[2][1] = 6.0;
        let (_, envs, _) = reply(&mut reported, 3, &contexts);
        assert_eq!(envs, [2]);
    }

    #[test]
    fn a_reply_the_client_missed_is_sent_again() {
        let mut reported = ReportedContexts::new(3, 2);
        let mut contexts = [[1.0, 2.0], [3.0, 4.0], [5.0, 6.0]];
        reply(&mut reported, 0, &contexts);
        contexts[0][0] = -1.0;
        // This reply is lost: the client still holds epoch 1.
        reply(&mut reported, 1, &contexts);
        contexts[1][0] = -3.0;
        let (epoch, envs, values) = reply(&mut reported, 1, &contexts);
        assert_eq!((epoch, envs), (3, vec![0, 1]));
        assert_eq!(values, [-1.0, 2.0, -3.0, 4.0]);
        // A client that lost its copy asks for every context again.
        let (_, envs, _) = reply(&mut reported, 0, &contexts);
        assert_eq!(envs, [0, 1, 2]);
    }

    /// Room for the contexts stamped in replies the client missed, those requests
    /// changed and those of the autoresets: for every one to a client that holds none
    /// or missed more than 16 replies.
    #[test]
    fn room_is_for_the_contexts_the_engine_knows_will_be_sent() {
        let n = 40;
        let room = |envs| context_update_max_len(envs, 2);
        let mut reported = ReportedContexts::new(n, 2);
        let mut contexts = vec![[0.0, 0.0]; n];
        // A reply to a client that applied `known`, the first `changed` contexts changed.
        let mut step = |reported: &mut ReportedContexts, known: u64, changed: usize| {
            contexts[..changed].iter_mut().for_each(|c| c[0] += 1.0);
            reply(reported, known, &contexts);
        };
        assert_eq!(reported.room(0, 0), room(n));
        step(&mut reported, 0, 0);
        assert_eq!(
            reported.room(1, 0),
            room(0),
            "nothing stamped after epoch 1"
        );
        assert_eq!(reported.room(1, 3), room(3), "3 autoresets");
        assert_eq!(reported.room(0, 0), room(n), "a client that holds none");
        step(&mut reported, 1, 3);
        step(&mut reported, 1, 5);
        assert_eq!(reported.room(3, 0), room(0));
        assert_eq!(reported.room(2, 0), room(5), "the reply of epoch 3 missed");
        assert_eq!(
            reported.room(1, 2),
            room(3 + 5 + 2),
            "two missed, 2 autoresets"
        );
        assert_eq!(reported.room(1, 38), room(n), "at most every one");
        reported.requested(4);
        reported.requested(1);
        assert_eq!(reported.room(3, 1), room(6), "5 requested");
        step(&mut reported, 3, 0);
        assert_eq!(reported.room(4, 0), room(0), "requests count once");
        for known in 4..20 {
            step(&mut reported, known, 0);
        }
        assert_eq!(reported.room(4, 0), room(0), "16 replies missed, counted");
        assert_eq!(reported.room(3, 0), room(n), "17 missed");
    }

    #[test]
    fn refuses_an_epoch_not_sent_yet() {
        let mut reported = ReportedContexts::new(2, 1);
        assert!(reported.start(1, 2).is_err());
        reported.start(0, 2).unwrap();
        reported.finish(0);
        assert!(reported.start(1, 2).is_ok());
        assert!(reported.start(2, 2).is_err());
    }

    #[test]
    fn contextless_tasks_send_empty_rows() {
        let mut reported = ReportedContexts::new(3, 0);
        for known in [0, 1] {
            let mut blocks = reported.start(known, 2).unwrap();
            assert_eq!(blocks.len(), 2);
            for (i, block) in blocks.iter_mut().enumerate() {
                block.note(0, &[]);
                if i == 0 {
                    block.note(1, &[]);
                }
            }
            drop(blocks);
            let update = reported.finish(known);
            // Every environment to a client that holds none, then none.
            let expected: &[u32] = if known == 0 { &[0, 1, 2] } else { &[] };
            assert_eq!(update.envs, expected);
            assert!(update.values.0.is_empty());
        }
    }
}
