//! A [`BatchStepReply`](super::BatchStepReply) encoded in place: each environment of a
//! batch writes its row straight into the reply's bytes.
//!
//! An engine steps thousands of environments per `step_batch`; filling column vectors
//! and then serializing them wrote every row twice more (a zeroed vector, then the
//! serializer's copy), 0.5 MiB per 4 096 obstacle environments. Here the rows' columns
//! are reserved inside the encoded message (in a `Vec`, or in any [`MessageBuffer`]: the
//! engine's are in shared memory, which Zenoh sends without a copy) and parallel tasks
//! fill disjoint blocks of them; the info columns, whose keys are known only after
//! stepping, are appended last (where the message's field order puts them) from each
//! task's block of values. Per
//! obstacle env-step that took cachegrind's count from 32.7 to 27.2 L1d misses and 5 419
//! to 5 234 instructions. Since 2026-12-04 the rows are not zeroed before the tasks write
//! them (see [`BatchStepWriter`]): 106 instructions and 1.5 last-level misses fewer per
//! obstacle env-step (cachegrind, a served engine of 4 096 environments, 40 steps, a
//! 1 MiB last level), and no pass over the whole reply on the request's thread before
//! the tasks start. The bytes are exactly those of `encode(&BatchStepReply { .. })` (a
//! test checks it), so clients decode the reply as any other.
//!
//! Layout (MessagePack, named fields, in [`BatchStepReply`](super::BatchStepReply)'s
//! order), for `n` environments with `d` observations each:
//!
//! ```text
//! map(6) "v" uint | "observations" bin(8 n d) | "rewards" bin(8 n)
//!        | "terminated" bin(n) | "truncated" bin(n) | "info" map(..)
//! ```
//!
//! A reply with a context update ([`BatchStepWriter::with_contexts_in`]) is a `map(7)`
//! whose rows leave the contexts out (`d` is then the state's length) and which ends with
//! `"contexts"` and the [`ContextUpdate`](super::ContextUpdate), appended after the info
//! columns.

use std::io;
use std::mem::{MaybeUninit, take};
use std::ops::Range;
use std::sync::atomic::{AtomicUsize, Ordering};

use super::{ContextUpdate, F64s, PROTOCOL_VERSION};

/// Memory a message is encoded into: a `Vec<u8>`, or a buffer of fixed size (the engine's
/// replies in Zenoh's shared memory) that moves what it holds to the heap when asked for
/// more room than it has.
pub trait MessageBuffer {
    /// Bytes written so far.
    fn len(&self) -> usize;

    /// Whether no byte is written yet.
    fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Makes room for at least `additional` bytes past [`len`](Self::len).
    fn reserve(&mut self, additional: usize);

    /// The room past [`len`](Self::len): at least what the last
    /// [`reserve`](Self::reserve) asked for.
    ///
    /// # Safety
    /// The caller writes only initialised bytes into it: the room may be memory that is
    /// read as bytes already (a shared-memory buffer is all bytes, whatever was in it).
    unsafe fn spare_capacity_mut(&mut self) -> &mut [MaybeUninit<u8>];

    /// Sets the length to `new_len`.
    ///
    /// # Safety
    /// `new_len` is at most `len` plus the spare room, and every byte below it is
    /// initialised.
    unsafe fn set_len(&mut self, new_len: usize);

    /// Appends `bytes`.
    fn extend_from_slice(&mut self, bytes: &[u8]) {
        self.reserve(bytes.len());
        let len = self.len();
        // SAFETY: `fill` writes initialised bytes, the room holds at least `bytes.len()`
        // (just reserved), and after it every byte below `len + bytes.len()` is written.
        unsafe {
            fill(&mut self.spare_capacity_mut()[..bytes.len()], bytes);
            self.set_len(len + bytes.len());
        }
    }
}

impl MessageBuffer for Vec<u8> {
    fn len(&self) -> usize {
        Vec::len(self)
    }

    fn reserve(&mut self, additional: usize) {
        Vec::reserve(self, additional);
    }

    unsafe fn spare_capacity_mut(&mut self) -> &mut [MaybeUninit<u8>] {
        Vec::spare_capacity_mut(self)
    }

    unsafe fn set_len(&mut self, new_len: usize) {
        // SAFETY: the caller's promise is `Vec::set_len`'s.
        unsafe { Vec::set_len(self, new_len) }
    }

    fn extend_from_slice(&mut self, bytes: &[u8]) {
        Vec::extend_from_slice(self, bytes);
    }
}

/// A [`MessageBuffer`] as an [`io::Write`], for MessagePack's encoder.
struct Appender<'a, B>(&'a mut B);

impl<B: MessageBuffer> io::Write for Appender<'_, B> {
    fn write(&mut self, bytes: &[u8]) -> io::Result<usize> {
        self.0.extend_from_slice(bytes);
        Ok(bytes.len())
    }

    fn flush(&mut self) -> io::Result<()> {
        Ok(())
    }
}

/// Where the parts of a reply of `num_envs` environments go, up to the info columns.
struct Layout {
    /// The message's first bytes: the map's header and the version.
    head: Vec<u8>,
    /// Each row column's header (its key and its bin's length), with where it starts.
    headers: Vec<(usize, Vec<u8>)>,
    observations: Range<usize>,
    rewards: Range<usize>,
    terminated: Range<usize>,
    truncated: Range<usize>,
}

impl Layout {
    /// `contexts`: the message ends with a `contexts` field after its info columns.
    fn new(num_envs: usize, observation_dim: usize, contexts: bool) -> Self {
        let mut head = Vec::new();
        write(rmp::encode::write_map_len(
            &mut head,
            6 + u32::from(contexts),
        ));
        write(rmp::encode::write_str(&mut head, "v"));
        write(rmp::encode::write_uint(
            &mut head,
            u64::from(PROTOCOL_VERSION),
        ));
        let lengths = [
            ("observations", 8 * num_envs * observation_dim),
            ("rewards", 8 * num_envs),
            ("terminated", num_envs),
            ("truncated", num_envs),
        ];
        // Each column's header right before its bytes.
        let mut headers = Vec::with_capacity(lengths.len());
        let mut columns = Vec::with_capacity(lengths.len());
        let mut offset = head.len();
        for (name, bytes) in lengths {
            let mut header = Vec::new();
            write(rmp::encode::write_str(&mut header, name));
            let length = u32::try_from(bytes).expect("a batch's column is under 4 GiB");
            write(rmp::encode::write_bin_len(&mut header, length));
            let header_len = header.len();
            headers.push((offset, header));
            offset += header_len;
            columns.push(offset..offset + bytes);
            offset += bytes;
        }
        let [observations, rewards, terminated, truncated] =
            <[Range<usize>; 4]>::try_from(columns).expect("four columns");
        Self {
            head,
            headers,
            observations,
            rewards,
            terminated,
            truncated,
        }
    }

    /// The length of the message up to its info columns.
    fn end(&self) -> usize {
        self.truncated.end
    }
}

/// A `step_batch` reply being written: the header and the rows' columns, then
/// [`finish`](Self::finish) appends the info columns.
///
/// The rows are not zeroed first: their bytes stay uninitialised capacity until the tasks
/// write them (zeroing 0.5 MiB per 4 096 obstacle environments cost the engine's request
/// thread a pass over the whole reply before any task began). [`BatchStepRows::push`]
/// writes a block's rows in order, each block counts the rows it wrote when it is dropped,
/// and `finish` takes the bytes only if the last [`rows`](Self::rows) wrote every row.
pub struct BatchStepWriter<B: MessageBuffer = Vec<u8>> {
    /// The message up to the first column's bytes; the columns and the headers between
    /// them are in its spare room, up to `end`.
    buffer: B,
    end: usize,
    observation_dim: usize,
    observations: Range<usize>,
    rewards: Range<usize>,
    terminated: Range<usize>,
    truncated: Range<usize>,
    /// Rows written through the blocks of the last [`rows`](Self::rows).
    rows_written: AtomicUsize,
    /// Whether the message ends with a `contexts` field
    /// ([`finish_with_contexts`](Self::finish_with_contexts)).
    contexts: bool,
}

/// Rows of a [`BatchStepWriter`]: all of them, or a block of them handed to one task,
/// written in order by [`push`](Self::push).
pub struct BatchStepRows<'a> {
    observation_dim: usize,
    observations: &'a mut [MaybeUninit<u8>],
    rewards: &'a mut [MaybeUninit<u8>],
    terminated: &'a mut [MaybeUninit<u8>],
    truncated: &'a mut [MaybeUninit<u8>],
    /// Rows `..written` are written.
    written: usize,
    /// The writer's count, which this block adds `written` to when dropped.
    rows_written: &'a AtomicUsize,
}

impl BatchStepWriter {
    /// The reply of `num_envs` environments with `observation_dim` observations each, in a
    /// `Vec`; `info_bytes` is room reserved for the info columns so that appending them
    /// does not move the rows (an estimate: more is allocated if needed).
    pub fn new(num_envs: usize, observation_dim: usize, info_bytes: usize) -> Self {
        Self::new_in(Vec::with_capacity, num_envs, observation_dim, info_bytes)
    }
}

impl<B: MessageBuffer> BatchStepWriter<B> {
    /// As [`BatchStepWriter::new`], written into the empty buffer `allocate` returns when
    /// given the reply's length with `info_bytes` of info columns.
    ///
    /// # Panics
    /// If that buffer holds bytes already.
    pub fn new_in(
        allocate: impl FnOnce(usize) -> B,
        num_envs: usize,
        observation_dim: usize,
        info_bytes: usize,
    ) -> Self {
        Self::start(allocate, num_envs, observation_dim, info_bytes, false)
    }

    /// As [`new_in`](Self::new_in), for a reply that leaves the contexts out of its
    /// observations (`state_dim` values per row) and ends with the
    /// [`ContextUpdate`](super::ContextUpdate) that
    /// [`finish_with_contexts`](Self::finish_with_contexts) appends; `tail_bytes` is room
    /// for the info columns and that update together ([`context_update_len`]).
    pub fn with_contexts_in(
        allocate: impl FnOnce(usize) -> B,
        num_envs: usize,
        state_dim: usize,
        tail_bytes: usize,
    ) -> Self {
        Self::start(allocate, num_envs, state_dim, tail_bytes, true)
    }

    /// `tail_bytes`: room reserved past the rows, for what `finish` or
    /// `finish_with_contexts` appends.
    fn start(
        allocate: impl FnOnce(usize) -> B,
        num_envs: usize,
        observation_dim: usize,
        tail_bytes: usize,
        contexts: bool,
    ) -> Self {
        let layout = Layout::new(num_envs, observation_dim, contexts);
        let end = layout.end();
        let mut buffer = allocate(end + tail_bytes);
        assert!(buffer.is_empty(), "a reply is written into an empty buffer");
        buffer.extend_from_slice(&layout.head);
        let len = buffer.len();
        buffer.reserve(end - len + tail_bytes);
        // SAFETY: only the headers' bytes are written, at places below `end`, inside the
        // room just reserved.
        let spare = unsafe { buffer.spare_capacity_mut() };
        for (at, header) in &layout.headers {
            fill(&mut spare[at - len..at - len + header.len()], header);
        }
        Self {
            buffer,
            end,
            observation_dim,
            observations: layout.observations,
            rewards: layout.rewards,
            terminated: layout.terminated,
            truncated: layout.truncated,
            rows_written: AtomicUsize::new(0),
            contexts,
        }
    }

    /// Length of the reply before its info columns, which [`finish`](Self::finish)
    /// appends.
    pub fn info_offset(&self) -> usize {
        self.end
    }

    /// Every row, to write: all of them, through these rows or the blocks they split into,
    /// before [`finish`](Self::finish). A new call starts the count again.
    pub fn rows(&mut self) -> BatchStepRows<'_> {
        *self.rows_written.get_mut() = 0;
        let len = self.buffer.len();
        // SAFETY: the rows are written with `push` and `push_failed`, which write
        // initialised bytes only.
        let spare = unsafe { &mut self.buffer.spare_capacity_mut()[..self.end - len] };
        // The columns follow one another, each after its own header.
        let at = |position: usize| position - len;
        let (_, rest) = spare.split_at_mut(at(self.observations.start));
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
            written: 0,
            rows_written: &self.rows_written,
        }
    }

    /// The encoded reply, with the info columns: each key, in increasing order, with its
    /// values block by block, `num_envs` in all (the blocks need not be the rows').
    ///
    /// # Panics
    /// If the last [`rows`](Self::rows) did not write every row, or a key's blocks do not
    /// hold `num_envs` values: the caller sized the reply for its own batch. If the writer
    /// was made [`with_contexts_in`](Self::with_contexts_in).
    pub fn finish<'a, I: IntoIterator<Item = InfoBlock<'a>>>(
        mut self,
        info: impl ExactSizeIterator<Item = (&'a str, I)>,
    ) -> B {
        assert!(!self.contexts, "this reply ends with its contexts");
        self.append_info(info);
        self.buffer
    }

    /// [`finish`](Self::finish) for a writer made
    /// [`with_contexts_in`](Self::with_contexts_in): the info columns, then `contexts`.
    ///
    /// # Panics
    /// As `finish`, and if the writer was made without contexts.
    pub fn finish_with_contexts<'a, I: IntoIterator<Item = InfoBlock<'a>>>(
        mut self,
        info: impl ExactSizeIterator<Item = (&'a str, I)>,
        contexts: &ContextUpdate,
    ) -> B {
        assert!(self.contexts, "this reply has no room for contexts");
        self.append_info(info);
        write_context_update(&mut Appender(&mut self.buffer), contexts);
        self.buffer
    }

    fn append_info<'a, I: IntoIterator<Item = InfoBlock<'a>>>(
        &mut self,
        info: impl ExactSizeIterator<Item = (&'a str, I)>,
    ) {
        let num_envs = self.terminated.len();
        assert_eq!(
            *self.rows_written.get_mut(),
            num_envs,
            "every one of the {num_envs} rows is written before the reply is finished"
        );
        // SAFETY: the room reaches `end` (reserved in `new_in`). Below `end`, `new_in`
        // wrote every column's header, and the last `rows` wrote every row: its blocks
        // cover the rows without overlap (`split_off_front`), each wrote its rows
        // `..written` in full (`push`), and their `written` add up to `num_envs`, the rows
        // of all blocks, so every block wrote all of its rows. The count was read after
        // every block was dropped: they borrow `self` mutably, and `finish` takes it by
        // value.
        unsafe { self.buffer.set_len(self.end) };
        let buffer = &mut self.buffer;
        write(rmp::encode::write_str(&mut Appender(buffer), "info"));
        let keys = u32::try_from(info.len()).expect("under 4 billion info keys");
        write(rmp::encode::write_map_len(&mut Appender(buffer), keys));
        let nan = f64::NAN.to_le_bytes();
        for (key, blocks) in info {
            write(rmp::encode::write_str(&mut Appender(buffer), key));
            let bytes = u32::try_from(8 * num_envs).expect("a batch's column is under 4 GiB");
            write(rmp::encode::write_bin_len(&mut Appender(buffer), bytes));
            let start = buffer.len();
            buffer.reserve(8 * num_envs);
            for block in blocks {
                match block {
                    InfoBlock::Values(values) => buffer.extend_from_slice(&F64s::le_bytes(values)),
                    InfoBlock::Missing(count) => {
                        (0..count).for_each(|_| buffer.extend_from_slice(&nan))
                    }
                }
            }
            assert_eq!(
                buffer.len() - start,
                8 * num_envs,
                "info `{key}` holds a value for each of {num_envs} environments"
            );
        }
    }
}

/// The bytes [`BatchStepWriter::finish_with_contexts`] appends for `contexts` after the
/// info columns.
pub fn context_update_len(contexts: &ContextUpdate) -> usize {
    let mut counter = ByteCounter(0);
    write_context_update(&mut counter, contexts);
    counter.0
}

/// The most bytes [`BatchStepWriter::finish_with_contexts`] appends for an update of
/// `envs` environments with `context_dim` values each: MessagePack's longest forms of the
/// key, the epoch, every index and the headers (47 bytes), and the values.
pub fn context_update_max_len(envs: usize, context_dim: usize) -> usize {
    // "contexts" 9, map(3) 1, "epoch" 6 + u64 9, "envs" 5 + array32 5, "values" 7 + bin32 5.
    const FIXED: usize = 47;
    // A u32 index: up to 5 bytes.
    FIXED + envs * (5 + 8 * context_dim)
}

fn write_context_update(writer: &mut impl io::Write, contexts: &ContextUpdate) {
    write(rmp::encode::write_str(writer, "contexts"));
    rmp_serde::encode::write_named(writer, contexts).expect("a context update encodes");
}

/// An [`io::Write`] that only counts the bytes.
struct ByteCounter(usize);

impl io::Write for ByteCounter {
    fn write(&mut self, bytes: &[u8]) -> io::Result<usize> {
        self.0 += bytes.len();
        Ok(bytes.len())
    }

    fn flush(&mut self) -> io::Result<()> {
        Ok(())
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
    ///
    /// # Panics
    /// If a row was written already: a block's count covers only its own pushes.
    pub fn blocks(mut self, rows: usize) -> Vec<Self> {
        assert_eq!(
            self.written, 0,
            "rows are split into blocks before any is written"
        );
        let rows = rows.max(1);
        let mut blocks = Vec::with_capacity(self.terminated.len().div_ceil(rows));
        while !self.terminated.is_empty() {
            let row = rows.min(self.terminated.len());
            blocks.push(self.split_off_front(row));
        }
        blocks
    }

    /// Takes rows `..row` off the front as a block of their own; none of these rows is
    /// written yet.
    fn split_off_front(&mut self, row: usize) -> Self {
        let observation_dim = self.observation_dim;
        let (observations, observations_tail) =
            take(&mut self.observations).split_at_mut(8 * observation_dim * row);
        let (rewards, rewards_tail) = take(&mut self.rewards).split_at_mut(8 * row);
        let (terminated, terminated_tail) = take(&mut self.terminated).split_at_mut(row);
        let (truncated, truncated_tail) = take(&mut self.truncated).split_at_mut(row);
        (
            self.observations,
            self.rewards,
            self.terminated,
            self.truncated,
        ) = (
            observations_tail,
            rewards_tail,
            terminated_tail,
            truncated_tail,
        );
        Self {
            observation_dim,
            observations,
            rewards,
            terminated,
            truncated,
            written: 0,
            rows_written: self.rows_written,
        }
    }

    /// Writes the next row.
    ///
    /// # Panics
    /// If every row is written already or `observation` is not `observation_dim` long: the
    /// caller sized the reply for its own batch.
    pub fn push(&mut self, observation: &[f64], reward: f64, terminated: bool, truncated: bool) {
        let i = self.written;
        assert!(i < self.terminated.len(), "a row past the block's last");
        assert_eq!(
            observation.len(),
            self.observation_dim,
            "observation length"
        );
        let width = 8 * self.observation_dim;
        fill(
            &mut self.observations[i * width..(i + 1) * width],
            &F64s::le_bytes(observation),
        );
        fill(&mut self.rewards[8 * i..8 * (i + 1)], &reward.to_le_bytes());
        self.terminated[i].write(u8::from(terminated));
        self.truncated[i].write(u8::from(truncated));
        self.written += 1;
    }

    /// Writes the next row as zeros: the row of an environment whose step failed, in a
    /// reply that will not be sent.
    pub fn push_failed(&mut self) {
        let i = self.written;
        assert!(i < self.terminated.len(), "a row past the block's last");
        let width = 8 * self.observation_dim;
        for byte in &mut self.observations[i * width..(i + 1) * width] {
            byte.write(0);
        }
        fill(&mut self.rewards[8 * i..8 * (i + 1)], &[0; 8]);
        self.terminated[i].write(0);
        self.truncated[i].write(0);
        self.written += 1;
    }
}

impl Drop for BatchStepRows<'_> {
    fn drop(&mut self) {
        self.rows_written.fetch_add(self.written, Ordering::Relaxed);
    }
}

/// Writes `bytes` into `to`, as one copy (a loop of `MaybeUninit::write` stays a loop of
/// single bytes: 0.5 k more instructions per obstacle env-step).
///
/// # Panics
/// If the lengths differ.
fn fill(to: &mut [MaybeUninit<u8>], bytes: &[u8]) {
    assert_eq!(
        to.len(),
        bytes.len(),
        "a row's bytes fill its place exactly"
    );
    // SAFETY: `MaybeUninit<u8>` has `u8`'s layout; `to` is borrowed exclusively and holds
    // exactly `bytes.len()` bytes, which cannot overlap `bytes` (a shared borrow).
    unsafe {
        std::ptr::copy_nonoverlapping(bytes.as_ptr(), to.as_mut_ptr().cast::<u8>(), bytes.len());
    }
}

/// Writing MessagePack into a `Vec` or a [`MessageBuffer`] cannot fail.
fn write<T, E: std::fmt::Debug>(result: Result<T, E>) -> T {
    result.expect("writing into memory cannot fail")
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;

    use serde_bytes::ByteBuf;

    use super::*;
    use crate::protocol::{BatchStepReply, ContextUpdate, encode};

    /// Rows set block by block, in any order, and info columns given block by block give
    /// the serializer's bytes for the same reply: with bins of every header size (8-, 16-
    /// and 32-bit lengths), no info, NaN info values and whole blocks without a key; with
    /// and without a context update at the end.
    #[test]
    fn rows_written_in_place_encode_as_the_serializer_does() {
        let cases = [(3, 2, 2), (5_000, 2, 1), (1, 0, 0), (0, 3, 0), (700, 7, 3)];
        for ((n, d, keys), with_contexts) in cases.into_iter().flat_map(|c| [(c, false), (c, true)])
        {
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

            // Every third environment's context, two values each.
            let contexts = with_contexts.then(|| {
                let envs: Vec<u32> = (0..n as u32).step_by(3).collect();
                let values = envs.iter().flat_map(|&i| [f64::from(i), -0.5]).collect();
                ContextUpdate {
                    epoch: 7 + n as u64,
                    envs,
                    values: F64s(values),
                }
            });
            let mut writer = match contexts {
                Some(_) => BatchStepWriter::with_contexts_in(Vec::with_capacity, n, d, 0),
                None => BatchStepWriter::new(n, d, 0),
            };
            // Blocks of 64 rows in reverse order: where a row lands cannot depend on
            // which task writes first.
            let mut blocks = writer.rows().blocks(64);
            for (block, rows) in blocks.iter_mut().enumerate().rev() {
                for i in 0..rows.terminated.len() {
                    let row = block * 64 + i;
                    rows.push(
                        &observations[row * d..(row + 1) * d],
                        rewards[row],
                        terminated[row] == 1,
                        truncated[row] == 1,
                    );
                }
            }
            drop(blocks);
            // Info in blocks of 100 values, a block of NaN given as missing.
            let info_blocks = info.iter().map(|(key, values)| {
                let blocks = values.0.chunks(100).map(|block| {
                    if block.iter().all(|v| v.is_nan()) {
                        InfoBlock::Missing(block.len())
                    } else {
                        InfoBlock::Values(block)
                    }
                });
                (key.as_str(), blocks)
            });
            let in_place = match &contexts {
                Some(update) => writer.finish_with_contexts(info_blocks, update),
                None => writer.finish(info_blocks),
            };

            let serialized = encode(&BatchStepReply {
                v: PROTOCOL_VERSION,
                observations: F64s(observations),
                rewards: F64s(rewards),
                terminated: ByteBuf::from(terminated),
                truncated: ByteBuf::from(truncated),
                info,
                contexts,
            });
            assert!(
                in_place == serialized,
                "n = {n}, d = {d}, {keys} info keys, contexts {with_contexts}"
            );
        }
    }

    /// The bytes counted for an update are those the writer appends for it, never more
    /// than the bound, which MessagePack's longest forms reach (an epoch of 9 bytes,
    /// indices of 5, and 32-bit array and bin lengths).
    #[test]
    fn a_context_update_takes_the_bytes_counted_and_at_most_the_bound() {
        let cases = [
            (0..0, 2, 1),
            (0..3, 2, 5),
            (100_000..100_300, 8, 1 << 40),
            (70_000..70_000 + 65_536, 1, u64::MAX),
        ];
        for (i, (envs, context_dim, epoch)) in cases.into_iter().enumerate() {
            let envs: Vec<u32> = envs.collect();
            let update = ContextUpdate {
                epoch,
                values: F64s(vec![0.5; envs.len() * context_dim]),
                envs,
            };
            let without = BatchStepWriter::new(0, 1, 0).finish(no_info());
            let with = BatchStepWriter::with_contexts_in(Vec::with_capacity, 0, 1, 0)
                .finish_with_contexts(no_info(), &update);
            let appended = with.len() - without.len();
            assert_eq!(context_update_len(&update), appended, "case {i}");
            let bound = context_update_max_len(update.envs.len(), context_dim);
            assert!(appended <= bound, "case {i}: {appended} > {bound}");
            if i == 3 {
                assert_eq!(appended, bound, "the longest forms");
            }
        }
    }

    /// Writes rows `0..n` of a reply of `n` environments with one observation each, row
    /// `i` holding `i`, in blocks of 4, leaving out the rows `skip` names.
    fn write_rows(writer: &mut BatchStepWriter, n: usize, skip: impl Fn(usize) -> bool) {
        for (block, mut rows) in writer.rows().blocks(4).into_iter().enumerate() {
            for row in (block * 4..n.min(block * 4 + 4)).take_while(|&row| !skip(row)) {
                rows.push(&[row as f64], 0.5, false, true);
            }
        }
    }

    fn no_info() -> std::iter::Empty<(&'static str, std::iter::Empty<InfoBlock<'static>>)> {
        std::iter::empty()
    }

    #[test]
    fn a_reply_is_finished_once_every_row_is_written() {
        let mut writer = BatchStepWriter::new(10, 1, 0);
        write_rows(&mut writer, 10, |_| false);
        let reply = writer.finish(no_info());
        let decoded: BatchStepReply = rmp_serde::from_slice(&reply).unwrap();
        assert_eq!(
            decoded.observations.0,
            (0..10).map(f64::from).collect::<Vec<_>>()
        );
        assert_eq!(decoded.truncated.as_ref(), &[1; 10]);
    }

    /// The rows' bytes are not initialised until written: a reply with a row left out
    /// must not be finished (its bytes would be read), whichever block left it out.
    #[test]
    fn a_reply_with_a_row_not_written_is_refused() {
        for missing in [0, 5, 9] {
            let refused = std::panic::catch_unwind(|| {
                let mut writer = BatchStepWriter::new(10, 1, 0);
                write_rows(&mut writer, 10, |row| row == missing);
                writer.finish(no_info())
            });
            assert!(refused.is_err(), "row {missing} left out");
        }
    }

    /// A second `rows` counts its own rows only: what counts is that one pass wrote them
    /// all, not that as many pushes were made in all.
    #[test]
    fn a_new_pass_over_the_rows_counts_again() {
        let refused = std::panic::catch_unwind(|| {
            let mut writer = BatchStepWriter::new(10, 1, 0);
            write_rows(&mut writer, 10, |row| row == 9);
            write_rows(&mut writer, 10, |row| row >= 4);
            writer.finish(no_info())
        });
        assert!(refused.is_err(), "two passes of 9 and 4 rows");
        let mut writer = BatchStepWriter::new(10, 1, 0);
        write_rows(&mut writer, 10, |row| row >= 5);
        write_rows(&mut writer, 10, |_| false);
        assert_eq!(
            writer.finish(no_info()).len(),
            BatchStepWriter::new(10, 1, 0).end + 6
        );
    }

    #[test]
    fn a_failed_row_is_zeros() {
        let mut writer = BatchStepWriter::new(3, 2, 0);
        let mut rows = writer.rows();
        rows.push(&[1.0, 2.0], 3.0, true, true);
        rows.push_failed();
        rows.push(&[4.0, 5.0], 6.0, false, false);
        drop(rows);
        let decoded: BatchStepReply = rmp_serde::from_slice(&writer.finish(no_info())).unwrap();
        assert_eq!(decoded.observations.0, [1.0, 2.0, 0.0, 0.0, 4.0, 5.0]);
        assert_eq!(decoded.rewards.0, [3.0, 0.0, 6.0]);
        assert_eq!(decoded.terminated.as_ref(), &[1, 0, 0]);
    }
}
