//! Large replies written straight into Zenoh's shared memory.
//!
//! Zenoh sends a payload larger than a few KiB to a peer on the same machine through
//! shared memory: by default it copies the payload there (its "transport optimization"),
//! on the thread that replies, after the payload is complete. A `step_batch` reply of
//! 4 096 obstacle environments is 0.6 MiB, and that copy took about 70 µs of a 1.2 ms
//! step. A reply encoded in a buffer that is shared memory already is sent as it is: its
//! rows are written there by the tasks that step the environments, in parallel.
//!
//! The buffer is taken from the pool Zenoh's transport optimization allocates from, so
//! the engine maps no memory of its own. When there is none to take (shared memory
//! disabled, the pool not set up yet or exhausted), or a reply outgrows its buffer, the
//! reply is written on the heap as before; a peer that cannot read shared memory (on
//! another machine) gets the bytes over the network either way.

use std::mem::MaybeUninit;
use std::num::NonZeroUsize;

use zenoh::Wait;
use zenoh::bytes::ZBytes;
use zenoh::shm::{JustAlloc, OwnedShmBuf, ZShmMut};

use crate::protocol::MessageBuffer;

/// Replies smaller than this are written on the heap: Zenoh's default threshold of its
/// transport optimization, below which a payload goes inline in the transport's batch.
const SHARED_FROM_BYTES: usize = 3072;

/// Where the engine writes its large replies.
pub(crate) struct ReplyMemory {
    zsession: zenoh::Session,
}

impl ReplyMemory {
    pub fn new(zsession: &zenoh::Session) -> Self {
        Self {
            zsession: zsession.clone(),
        }
    }

    /// A buffer for a reply of about `capacity` bytes: shared memory if there is some to
    /// take, the heap otherwise.
    pub fn buffer(&self, capacity: usize) -> ReplyBuffer {
        if capacity >= SHARED_FROM_BYTES
            && let Some(provider) = self.zsession.get_shm_provider().into_option()
        {
            let alloc = || provider.alloc(capacity).with_policy::<JustAlloc>().wait();
            // Buffers the clients have released are reclaimed only when the pool is full.
            // Zenoh's `GarbageCollect` policy then tries again only if one of them alone
            // is as large as the new buffer, though its allocator merges them: a reply
            // larger than the ones before it (at a step where every environment
            // autoresets, say) would go to the heap with the pool all but empty.
            let memory = alloc().or_else(|_| {
                provider.garbage_collect();
                alloc()
            });
            if let Ok(memory) = memory {
                return ReplyBuffer::Shared { memory, len: 0 };
            }
        }
        ReplyBuffer::Heap(Vec::with_capacity(capacity))
    }
}

/// A reply being written: in a shared-memory buffer of fixed size, or on the heap, where
/// it moves if it outgrows the shared one.
pub(crate) enum ReplyBuffer {
    /// Bytes `..len` of `memory` are written.
    Shared {
        memory: ZShmMut,
        len: usize,
    },
    Heap(Vec<u8>),
}

impl ReplyBuffer {
    /// Whether the bytes are in shared memory.
    #[cfg(test)]
    pub fn is_shared(&self) -> bool {
        matches!(self, Self::Shared { .. })
    }
}

impl MessageBuffer for ReplyBuffer {
    fn len(&self) -> usize {
        match self {
            Self::Shared { len, .. } => *len,
            Self::Heap(bytes) => bytes.len(),
        }
    }

    fn reserve(&mut self, additional: usize) {
        match self {
            Self::Shared { memory, len } if *len + additional > memory.len() => {
                let mut bytes = Vec::with_capacity(*len + additional);
                bytes.extend_from_slice(&memory[..*len]);
                *self = Self::Heap(bytes);
            }
            Self::Shared { .. } => {}
            Self::Heap(bytes) => bytes.reserve(additional),
        }
    }

    unsafe fn spare_capacity_mut(&mut self) -> &mut [MaybeUninit<u8>] {
        match self {
            Self::Shared { memory, len } => {
                let spare: &mut [u8] = &mut memory[*len..];
                // SAFETY: `MaybeUninit<u8>` has `u8`'s layout, and the caller writes only
                // initialised bytes (this method's contract), so the memory stays valid
                // as the bytes `memory` hands out.
                unsafe { &mut *(std::ptr::from_mut(spare) as *mut [MaybeUninit<u8>]) }
            }
            Self::Heap(bytes) => bytes.spare_capacity_mut(),
        }
    }

    unsafe fn set_len(&mut self, new_len: usize) {
        match self {
            Self::Shared { memory, len } => {
                assert!(new_len <= memory.len(), "a length within the buffer");
                *len = new_len;
            }
            // SAFETY: the caller's promise is `Vec::set_len`'s.
            Self::Heap(bytes) => unsafe { bytes.set_len(new_len) },
        }
    }
}

impl From<ReplyBuffer> for ZBytes {
    /// The written bytes as a payload: the shared buffer cut to them, without a copy.
    fn from(buffer: ReplyBuffer) -> Self {
        match buffer {
            ReplyBuffer::Shared { mut memory, len } => match NonZeroUsize::new(len) {
                Some(size) if memory.try_resize(size).is_some() => memory.into(),
                // Nothing written, or a buffer that cannot shrink: copy what was written.
                _ => ZBytes::from(memory[..len].to_vec()),
            },
            ReplyBuffer::Heap(bytes) => bytes.into(),
        }
    }
}

#[cfg(test)]
mod tests {
    use zenoh::shm::ShmProviderBuilder;

    use super::*;
    use crate::protocol::{BatchStepWriter, InfoBlock};

    fn shared(capacity: usize) -> ReplyBuffer {
        let provider = ShmProviderBuilder::default_backend(1 << 20)
            .wait()
            .expect("a shared-memory pool of 1 MiB");
        let memory = provider
            .alloc(capacity)
            .wait()
            .expect("a buffer of the pool");
        ReplyBuffer::Shared { memory, len: 0 }
    }

    /// A reply that fits stays in shared memory and is sent cut to what was written.
    #[test]
    fn a_reply_that_fits_is_sent_from_shared_memory() {
        let mut buffer = shared(4096);
        buffer.extend_from_slice(&[7; 1000]);
        buffer.reserve(3000);
        buffer.extend_from_slice(&[8; 96]);
        assert!(buffer.is_shared());
        let payload = ZBytes::from(buffer);
        let shm = payload.as_shm().expect("the payload is the shared buffer");
        assert_eq!(shm.len(), 1096);
        let bytes = payload.to_bytes();
        assert_eq!(&bytes[..1000], &[7; 1000]);
        assert_eq!(&bytes[1000..], &[8; 96]);
    }

    /// A reply that outgrows its shared buffer moves to the heap with what it held, and
    /// goes on there.
    #[test]
    fn a_reply_that_outgrows_its_buffer_moves_to_the_heap_whole() {
        let mut buffer = shared(4096);
        buffer.extend_from_slice(&[1; 4000]);
        buffer.extend_from_slice(&[2; 200]);
        assert!(!buffer.is_shared());
        buffer.extend_from_slice(&[3; 10]);
        let payload = ZBytes::from(buffer);
        assert!(payload.as_shm().is_none());
        let bytes = payload.to_bytes();
        assert_eq!(bytes.len(), 4210);
        assert!(bytes[..4000].iter().all(|&b| b == 1));
        assert!(bytes[4000..4200].iter().all(|&b| b == 2));
        assert!(bytes[4200..].iter().all(|&b| b == 3));
    }

    /// A batch reply written into shared memory is byte for byte the one written on the
    /// heap: with room for its info columns, and without, when it moves to the heap at
    /// its first info column.
    #[test]
    fn a_batch_reply_in_shared_memory_is_the_one_on_the_heap() {
        let (n, d) = (300, 2);
        let values: Vec<f64> = (0..n).map(|i| i as f64 / 3.0).collect();
        let write = |mut writer: BatchStepWriter<ReplyBuffer>| {
            let blocks = writer.rows().blocks(64).into_iter();
            for (mut rows, block) in blocks.zip(values.chunks(64)) {
                for &value in block {
                    rows.push(&[value, -value], 0.5 * value, value > 50.0, false);
                }
            }
            let info = [
                ("a", [InfoBlock::Values(&values[..])]),
                ("b", [InfoBlock::Missing(n)]),
            ];
            writer.finish(info.into_iter())
        };
        let on_heap = write(BatchStepWriter::new_in(
            |_| ReplyBuffer::Heap(Vec::new()),
            n,
            d,
            0,
        ));
        let ReplyBuffer::Heap(expected) = &on_heap else {
            panic!("a heap buffer stays on the heap");
        };
        for (info_bytes, stays_shared) in [(2 * (8 * n + 64), true), (0, false)] {
            let reply = write(BatchStepWriter::new_in(shared, n, d, info_bytes));
            assert_eq!(
                reply.is_shared(),
                stays_shared,
                "room for {info_bytes} info bytes"
            );
            assert!(
                *ZBytes::from(reply).to_bytes() == expected[..],
                "room for {info_bytes} info bytes"
            );
        }
    }
}
