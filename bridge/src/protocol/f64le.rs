//! Real vectors on the wire: one MessagePack `bin` holding little-endian IEEE-754 `f64`s.
//!
//! ```text
//! bin 8   n·8 bytes
//! ┌──────┬────────┬──────────┬─────┬──────────────┐
//! │ 0xc4…│ length │ x₀ (f64le)│ …  │ xₙ₋₁ (f64le) │
//! └──────┴────────┴──────────┴─────┴──────────────┘
//! ```
//!
//! numpy reads it without a copy (`np.frombuffer(b, "<f8")`), and any MessagePack library
//! writes it from a byte string. Hand-written clients may send a plain MessagePack array
//! of numbers instead; it is accepted too.

use std::borrow::Cow;
use std::fmt;

use serde::de::{self, SeqAccess, Visitor};
use serde::{Deserialize, Deserializer, Serialize, Serializer};

/// A vector of reals encoded as little-endian `f64` bytes.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct F64s(pub Vec<f64>);

impl F64s {
    /// `values` as little-endian bytes: their own memory on a little-endian CPU (a batch
    /// reply carries megabytes of them), a converted copy elsewhere.
    pub fn le_bytes(values: &[f64]) -> Cow<'_, [u8]> {
        if cfg!(target_endian = "little") {
            // SAFETY: any initialised memory is valid as bytes, `u8` has no alignment
            // requirement, and the length covers exactly the slice's `8 len` bytes.
            Cow::Borrowed(unsafe {
                std::slice::from_raw_parts(values.as_ptr().cast::<u8>(), size_of_val(values))
            })
        } else {
            Cow::Owned(values.iter().flat_map(|v| v.to_le_bytes()).collect())
        }
    }

    /// Decodes little-endian `f64` bytes; `None` if the length is not a multiple of 8. On a
    /// little-endian CPU one copy of the bytes (every batch request and reply is decoded
    /// here; converting them one by one took 7 % of a Python client's CPU per step of 4 096
    /// limit-cycle environments), a conversion of each value elsewhere.
    pub fn from_le_bytes(bytes: &[u8]) -> Option<Vec<f64>> {
        if !bytes.len().is_multiple_of(8) {
            return None;
        }
        let len = bytes.len() / 8;
        if cfg!(target_endian = "little") {
            let mut values = Vec::<f64>::with_capacity(len);
            // SAFETY: the allocation holds `len` f64s, `bytes.len()` bytes, which the copy
            // fills entirely before `set_len`; any 8 bytes are a valid `f64`, and a
            // byte-wise copy has no alignment requirement.
            unsafe {
                std::ptr::copy_nonoverlapping(
                    bytes.as_ptr(),
                    values.as_mut_ptr().cast::<u8>(),
                    bytes.len(),
                );
                values.set_len(len);
            }
            Some(values)
        } else {
            Some(bytes.chunks_exact(8).map(f64_from_le_chunk).collect())
        }
    }
}

/// One little-endian `f64` from a chunk of exactly 8 bytes.
fn f64_from_le_chunk(chunk: &[u8]) -> f64 {
    f64::from_le_bytes(chunk.try_into().expect("chunks of 8"))
}

impl From<Vec<f64>> for F64s {
    fn from(values: Vec<f64>) -> Self {
        Self(values)
    }
}

impl Serialize for F64s {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        F64Slice(&self.0).serialize(serializer)
    }
}

/// Values encoded exactly as [`F64s`] encodes them, read from memory the caller keeps: a
/// client sends a batch's actions without copying them into a vector first.
#[derive(Clone, Copy, Debug)]
pub struct F64Slice<'a>(pub &'a [f64]);

impl Serialize for F64Slice<'_> {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.serialize_bytes(&F64s::le_bytes(self.0))
    }
}

/// An [`F64s`] read in place: its little-endian bytes, borrowed from the message. A client
/// copies a batch reply's columns once, from the payload straight to where it keeps them.
/// Only the `bin` form, the one engines send.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct F64Bin<'a>(pub &'a [u8]);

impl F64Bin<'_> {
    /// How many values the bytes hold.
    pub fn len(&self) -> usize {
        self.0.len() / 8
    }

    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }
}

impl<'de: 'a, 'a> Deserialize<'de> for F64Bin<'a> {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        deserializer.deserialize_bytes(F64BinVisitor)
    }
}

struct F64BinVisitor;

impl<'de> Visitor<'de> for F64BinVisitor {
    type Value = F64Bin<'de>;

    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str("a bin of little-endian f64 (length a multiple of 8)")
    }

    fn visit_borrowed_bytes<E: de::Error>(self, bytes: &'de [u8]) -> Result<F64Bin<'de>, E> {
        if bytes.len().is_multiple_of(8) {
            Ok(F64Bin(bytes))
        } else {
            Err(E::custom(format!(
                "f64 byte string of {} bytes is not a multiple of 8",
                bytes.len()
            )))
        }
    }
}

/// Runs `write` on the memory of `values` as bytes, where it writes little-endian `f64`s,
/// and leaves `values` holding them: their own bytes on a little-endian CPU, byte-swapped
/// after `write` elsewhere. Every bit pattern is an `f64`, so whatever `write` leaves is
/// a value.
pub fn write_le_bytes<R>(values: &mut [f64], write: impl FnOnce(&mut [u8]) -> R) -> R {
    // SAFETY: the bytes are exactly the slice's `8 len`, borrowed mutably for the call
    // only; `u8` has no alignment requirement and any byte pattern is a valid `f64`.
    let bytes = unsafe {
        std::slice::from_raw_parts_mut(values.as_mut_ptr().cast::<u8>(), size_of_val(values))
    };
    let result = write(bytes);
    if cfg!(target_endian = "big") {
        for value in values.iter_mut() {
            *value = f64::from_bits(value.to_bits().swap_bytes());
        }
    }
    result
}

impl<'de> Deserialize<'de> for F64s {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        deserializer.deserialize_any(F64sVisitor)
    }
}

struct F64sVisitor;

impl<'de> Visitor<'de> for F64sVisitor {
    type Value = F64s;

    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str("a bin of little-endian f64 (length a multiple of 8) or an array of numbers")
    }

    fn visit_bytes<E: de::Error>(self, bytes: &[u8]) -> Result<F64s, E> {
        F64s::from_le_bytes(bytes).map(F64s).ok_or_else(|| {
            E::custom(format!(
                "f64 byte string of {} bytes is not a multiple of 8",
                bytes.len()
            ))
        })
    }

    fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<F64s, A::Error> {
        let mut values = Vec::with_capacity(seq.size_hint().unwrap_or(0).min(1 << 16));
        while let Some(v) = seq.next_element::<f64>()? {
            values.push(v);
        }
        Ok(F64s(values))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn from_le_bytes_gives_every_value_bit_for_bit() {
        // Every bit pattern class: NaNs with payloads, infinities, signed zeros,
        // subnormals, and pseudo-random patterns, at every length up to 41 values.
        let mut state = 0x9e37_79b9_7f4a_7c15_u64;
        let mut patterns = vec![
            0x7ff8_dead_beef_0001,
            0xfff0_0000_0000_0001,
            0x7ff0_0000_0000_0000,
            0x8000_0000_0000_0000,
            0x0000_0000_0000_0001,
            0x800f_ffff_ffff_ffff,
        ];
        patterns.extend((0..35).map(|_| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        }));
        let bytes: Vec<u8> = patterns.iter().flat_map(|p| p.to_le_bytes()).collect();
        for len in 0..=patterns.len() {
            let decoded = F64s::from_le_bytes(&bytes[..8 * len]).expect("whole values");
            let expected: Vec<u64> = bytes[..8 * len]
                .chunks_exact(8)
                .map(|c| f64_from_le_chunk(c).to_bits())
                .collect();
            let bits: Vec<u64> = decoded.iter().map(|v| v.to_bits()).collect();
            assert_eq!(bits, expected, "{len} values");
            assert_eq!(bits, patterns[..len], "{len} values");
        }
        for len in [1, 7, 9, 15] {
            assert_eq!(F64s::from_le_bytes(&bytes[..len]), None, "{len} bytes");
        }
    }

    #[test]
    fn bin_and_array_forms_decode_to_the_same_values() {
        let values = vec![1.5, -0.0, f64::INFINITY, 1e-300];
        let bin = rmp_serde::to_vec(&F64s(values.clone())).unwrap();
        assert_eq!(bin[0], 0xc4, "encoded as bin 8");
        assert_eq!(rmp_serde::from_slice::<F64s>(&bin).unwrap().0, values);
        let array = rmp_serde::to_vec(&values).unwrap();
        assert_eq!(rmp_serde::from_slice::<F64s>(&array).unwrap().0, values);
    }

    /// The wire bytes are each value's own little-endian bytes, in order, whatever the
    /// CPU's byte order (NaN payloads and signed zeros included).
    #[test]
    fn le_bytes_are_the_values_little_endian_bytes_in_order() {
        let values = [
            1.5,
            -0.0,
            f64::from_bits(0x7ff8_dead_beef_0001),
            -3e-310,
            1e300,
        ];
        let expected: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        assert_eq!(&*F64s::le_bytes(&values), &expected[..]);
        let bin = rmp_serde::to_vec(&F64s(values.to_vec())).unwrap();
        assert_eq!(&bin[2..], &expected[..], "after the bin 8 header");
    }

    /// What a [`F64Slice`] encodes reads back, in place, as the same values: its bytes
    /// borrowed by [`F64Bin`], written into `f64` memory by [`write_le_bytes`].
    #[test]
    fn a_slice_encodes_as_f64s_and_reads_back_in_place() {
        let values = [1.5, -0.0, f64::from_bits(0x7ff8_dead_beef_0001), -3e-310];
        let encoded = rmp_serde::to_vec(&F64Slice(&values)).unwrap();
        assert_eq!(encoded, rmp_serde::to_vec(&F64s(values.to_vec())).unwrap());
        let bin: F64Bin = rmp_serde::from_slice(&encoded).unwrap();
        assert_eq!(bin.len(), values.len());
        let mut read = [7.0; 4];
        write_le_bytes(&mut read, |bytes| bytes.copy_from_slice(bin.0));
        let bits = |v: &[f64]| v.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&read), bits(&values));
        let ragged = rmp_serde::to_vec(&serde_bytes::Bytes::new(&[0u8; 7])).unwrap();
        assert!(rmp_serde::from_slice::<F64Bin>(&ragged).is_err());
        let array = rmp_serde::to_vec(&values).unwrap();
        assert!(
            rmp_serde::from_slice::<F64Bin>(&array).is_err(),
            "the array form"
        );
    }

    #[test]
    fn ragged_byte_string_is_an_error() {
        let bin = rmp_serde::to_vec(&serde_bytes::Bytes::new(&[0u8; 7])).unwrap();
        assert!(rmp_serde::from_slice::<F64s>(&bin).is_err());
    }
}
