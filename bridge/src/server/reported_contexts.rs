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

use std::ops::Range;

use crate::protocol::{ContextUpdate, ErrorCode, ErrorReply, F64s};

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
        }
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
        for (i, &changed_at) in self.changed_at.iter().enumerate() {
            if changed_at > known {
                update
                    .envs
                    .push(u32::try_from(i).expect("under 4 billion environments"));
                update.values.0.extend_from_slice(&self.values[self.row(i)]);
            }
        }
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
