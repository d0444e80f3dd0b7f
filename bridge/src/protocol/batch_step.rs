//! A [`BatchStepReply`](super::BatchStepReply) encoded in place: each environment of a
//! batch writes its row straight into the reply's bytes.
//!
//! An engine steps thousands of environments per `step_batch`; filling column vectors
//! and then serializing them wrote every row twice more (a zeroed vector, then the
//! serializer's copy), 0.5 MiB per 4 096 obstacle environments. Here the rows' columns
//! are reserved inside the encoded message and parallel tasks fill disjoint blocks of
//! them; the info columns, whose keys are known only after stepping, are appended last
//! (where the message's field order puts them) from each task's block of values. Per
//! obstacle env-step that took cachegrind's count from 32.7 to 27.2 L1d misses and 5 419
//! to 5 234 instructions. The bytes are exactly those of `encode(&BatchStepReply { .. })`
//! (a test checks it), so clients decode the reply as any other.
//!
//! Layout (MessagePack, named fields, in [`BatchStepReply`](super::BatchStepReply)'s
//! order), for `n` environments with `d` observations each:
//!
//! ```text
//! map(6) "v" uint | "observations" bin(8 n d) | "rewards" bin(8 n)
//!        | "terminated" bin(n) | "truncated" bin(n) | "info" map(..)
//! ```

use std::ops::Range;

use super::{F64s, PROTOCOL_VERSION};

/// A `step_batch` reply being written: the header and the rows' columns, then
/// [`finish`](Self::finish) appends the info columns.
pub struct BatchStepWriter {
    buffer: Vec<u8>,
    observation_dim: usize,
    observations: Range<usize>,
    rewards: Range<usize>,
    terminated: Range<usize>,
    truncated: Range<usize>,
}

/// Rows of a [`BatchStepWriter`]: all of them, or a block of them handed to one task.
pub struct BatchStepRows<'a> {
    observation_dim: usize,
    observations: &'a mut [u8],
    rewards: &'a mut [u8],
    terminated: &'a mut [u8],
    truncated: &'a mut [u8],
}

impl BatchStepWriter {
    /// The reply of `num_envs` environments with `observation_dim` observations each, every
    /// row zero until set; `info_bytes` is room reserved for the info columns so that
    /// appending them does not move the rows (an estimate: more is allocated if needed).
    pub fn new(num_envs: usize, observation_dim: usize, info_bytes: usize) -> Self {
        let rows_bytes = num_envs * (8 * observation_dim + 8 + 2);
        // Map, keys and bin headers: under 64 bytes.
        let mut buffer = Vec::with_capacity(64 + rows_bytes + info_bytes);
        write(rmp::encode::write_map_len(&mut buffer, 6));
        write(rmp::encode::write_str(&mut buffer, "v"));
        write(rmp::encode::write_uint(
            &mut buffer,
            u64::from(PROTOCOL_VERSION),
        ));
        let mut column = |name: &str, bytes: usize| {
            write(rmp::encode::write_str(&mut buffer, name));
            let length = u32::try_from(bytes).expect("a batch's column is under 4 GiB");
            write(rmp::encode::write_bin_len(&mut buffer, length));
            let start = buffer.len();
            buffer.resize(start + bytes, 0);
            start..buffer.len()
        };
        let observations = column("observations", 8 * num_envs * observation_dim);
        let rewards = column("rewards", 8 * num_envs);
        let terminated = column("terminated", num_envs);
        let truncated = column("truncated", num_envs);
        Self {
            buffer,
            observation_dim,
            observations,
            rewards,
            terminated,
            truncated,
        }
    }

    /// Every row, to set.
    pub fn rows(&mut self) -> BatchStepRows<'_> {
        // The columns follow one another, each after its own header.
        let (_, rest) = self.buffer.split_at_mut(self.observations.start);
        let (observations, rest) = rest.split_at_mut(self.observations.len());
        let (_, rest) = rest.split_at_mut(self.rewards.start - self.observations.end);
        let (rewards, rest) = rest.split_at_mut(self.rewards.len());
        let (_, rest) = rest.split_at_mut(self.terminated.start - self.rewards.end);
        let (terminated, rest) = rest.split_at_mut(self.terminated.len());
        let (_, rest) = rest.split_at_mut(self.truncated.start - self.terminated.end);
        let (truncated, _) = rest.split_at_mut(self.truncated.len());
        BatchStepRows {
            observation_dim: self.observation_dim,
            observations,
            rewards,
            terminated,
            truncated,
        }
    }

    /// The encoded reply, with the info columns: each key, in increasing order, with its
    /// values block by block, `num_envs` in all (the blocks need not be the rows').
    ///
    /// # Panics
    /// If a key's blocks do not hold `num_envs` values: the caller sized the reply for its
    /// own batch.
    pub fn finish<'a, B: IntoIterator<Item = InfoBlock<'a>>>(
        mut self,
        info: impl ExactSizeIterator<Item = (&'a str, B)>,
    ) -> Vec<u8> {
        let num_envs = self.terminated.len();
        write(rmp::encode::write_str(&mut self.buffer, "info"));
        let keys = u32::try_from(info.len()).expect("under 4 billion info keys");
        write(rmp::encode::write_map_len(&mut self.buffer, keys));
        for (key, blocks) in info {
            write(rmp::encode::write_str(&mut self.buffer, key));
            let bytes = u32::try_from(8 * num_envs).expect("a batch's column is under 4 GiB");
            write(rmp::encode::write_bin_len(&mut self.buffer, bytes));
            let start = self.buffer.len();
            for block in blocks {
                match block {
                    InfoBlock::Values(values) => {
                        self.buffer.extend_from_slice(&F64s::le_bytes(values));
                    }
                    InfoBlock::Missing(count) => {
                        let nan = f64::NAN.to_le_bytes();
                        self.buffer.extend((0..count).flat_map(|_| nan));
                    }
                }
            }
            assert_eq!(
                self.buffer.len() - start,
                8 * num_envs,
                "info `{key}` holds a value for each of {num_envs} environments"
            );
        }
        self.buffer
    }
}

/// A block of consecutive environments' values of one info column.
#[derive(Clone, Copy, Debug)]
pub enum InfoBlock<'a> {
    /// Their values (NaN where one did not report the key).
    Values(&'a [f64]),
    /// This many environments, none of which reported the key: NaN for each.
    Missing(usize),
}

impl<'a> BatchStepRows<'a> {
    /// The rows in consecutive blocks of `rows` (the last may be shorter), for one task
    /// each; block `k` starts at row `k · rows`.
    pub fn blocks(self, rows: usize) -> Vec<Self> {
        let rows = rows.max(1);
        let mut blocks = Vec::with_capacity(self.terminated.len().div_ceil(rows));
        let mut rest = self;
        while !rest.terminated.is_empty() {
            let row = rows.min(rest.terminated.len());
            let (block, tail) = rest.split_at(row);
            blocks.push(block);
            rest = tail;
        }
        blocks
    }

    /// Rows `..row` and `row..`.
    fn split_at(self, row: usize) -> (Self, Self) {
        let observation_dim = self.observation_dim;
        let (observations, observations_tail) =
            self.observations.split_at_mut(8 * observation_dim * row);
        let (rewards, rewards_tail) = self.rewards.split_at_mut(8 * row);
        let (terminated, terminated_tail) = self.terminated.split_at_mut(row);
        let (truncated, truncated_tail) = self.truncated.split_at_mut(row);
        (
            Self {
                observation_dim,
                observations,
                rewards,
                terminated,
                truncated,
            },
            Self {
                observation_dim,
                observations: observations_tail,
                rewards: rewards_tail,
                terminated: terminated_tail,
                truncated: truncated_tail,
            },
        )
    }

    /// Sets row `i`.
    ///
    /// # Panics
    /// If `i` is outside the rows or `observation` is not `observation_dim` long: the
    /// caller sized the reply for its own batch.
    pub fn set(
        &mut self,
        i: usize,
        observation: &[f64],
        reward: f64,
        terminated: bool,
        truncated: bool,
    ) {
        let width = 8 * self.observation_dim;
        self.observations[i * width..(i + 1) * width].copy_from_slice(&F64s::le_bytes(observation));
        self.rewards[8 * i..8 * (i + 1)].copy_from_slice(&reward.to_le_bytes());
        self.terminated[i] = u8::from(terminated);
        self.truncated[i] = u8::from(truncated);
    }
}

/// Writing MessagePack into a `Vec` cannot fail.
fn write<T, E: std::fmt::Debug>(result: Result<T, E>) -> T {
    result.expect("writing to a Vec cannot fail")
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;

    use serde_bytes::ByteBuf;

    use super::*;
    use crate::protocol::{BatchStepReply, encode};

    /// Rows set block by block, in any order, and info columns given block by block give
    /// the serializer's bytes for the same reply: with bins of every header size (8-, 16-
    /// and 32-bit lengths), no info, NaN info values and whole blocks without a key.
    #[test]
    fn rows_written_in_place_encode_as_the_serializer_does() {
        for (n, d, keys) in [(3, 2, 2), (5_000, 2, 1), (1, 0, 0), (0, 3, 0), (700, 7, 3)] {
            let value = |i: usize, j: usize| (i * 31 + j) as f64 * 0.25 - 3.0;
            let observations: Vec<f64> = (0..n * d).map(|k| value(k / d.max(1), k)).collect();
            let rewards: Vec<f64> = (0..n).map(|i| -(i as f64) / 7.0).collect();
            let terminated: Vec<u8> = (0..n).map(|i| u8::from(i % 3 == 1)).collect();
            let truncated: Vec<u8> = (0..n).map(|i| u8::from(i % 5 == 4)).collect();
            let info: BTreeMap<String, F64s> = (0..keys)
                .map(|k| {
                    // Key `k` is missing from every third block of 100 environments
                    // from block `k` on, and from single environments elsewhere.
                    let missing = |i: usize| i % 4 == k || (i / 100) % 3 == k;
                    let column = (0..n).map(|i| if missing(i) { f64::NAN } else { value(i, k) });
                    (format!("key{k}"), F64s(column.collect()))
                })
                .collect();

            let mut writer = BatchStepWriter::new(n, d, 0);
            // Blocks of 64 rows in reverse order: where a row lands cannot depend on
            // which task writes first.
            let mut blocks = writer.rows().blocks(64);
            for (block, rows) in blocks.iter_mut().enumerate().rev() {
                for i in 0..rows.terminated.len() {
                    let row = block * 64 + i;
                    rows.set(
                        i,
                        &observations[row * d..(row + 1) * d],
                        rewards[row],
                        terminated[row] == 1,
                        truncated[row] == 1,
                    );
                }
            }
            // Info in blocks of 100 values, a block of NaN given as missing.
            let in_place = writer.finish(info.iter().map(|(key, values)| {
                let blocks = values.0.chunks(100).map(|block| {
                    if block.iter().all(|v| v.is_nan()) {
                        InfoBlock::Missing(block.len())
                    } else {
                        InfoBlock::Values(block)
                    }
                });
                (key.as_str(), blocks)
            }));

            let serialized = encode(&BatchStepReply {
                v: PROTOCOL_VERSION,
                observations: F64s(observations),
                rewards: F64s(rewards),
                terminated: ByteBuf::from(terminated),
                truncated: ByteBuf::from(truncated),
                info,
            });
            assert!(in_place == serialized, "n = {n}, d = {d}, {keys} info keys");
        }
    }
}
