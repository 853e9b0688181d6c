//! Compact float columns and shared validation helpers.
//!
//! Float columns (`Vec<f32>`) travel as one MessagePack `bin` holding the little-endian IEEE-754
//! bytes, 4 bytes per value, instead of an array of tagged floats (5 bytes per value and a
//! per-element decode). Other languages read them with e.g. `numpy.frombuffer(b, "<f4")`.

use std::borrow::Cow;
use std::fmt;

use serde::de::{self, Visitor};
use serde::{Deserializer, Serializer};

use crate::error::ValidationError;

/// Serialises a `Vec<f32>` as little-endian bytes in one `bin` (use with `#[serde(with)]`).
pub(crate) mod f32_le {
    use super::*;

    pub(crate) fn serialize<S: Serializer>(values: &[f32], s: S) -> Result<S::Ok, S::Error> {
        s.serialize_bytes(&f32_le_bytes(values))
    }

    pub(crate) fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<f32>, D::Error> {
        d.deserialize_bytes(F32Visitor)
    }
}

/// The little-endian bytes of `values` (the exact bytes that travel and that the weight
/// checksum covers). Borrowed without copying on little-endian machines.
pub fn f32_le_bytes(values: &[f32]) -> Cow<'_, [u8]> {
    #[cfg(target_endian = "little")]
    {
        // SAFETY: `f32` has no padding and every byte of it is initialised; `u8` has alignment
        // 1 and no invalid values; the length in bytes is exactly `4 * values.len()` and the
        // borrow keeps `values` alive and immutable for the returned slice's lifetime.
        Cow::Borrowed(unsafe {
            std::slice::from_raw_parts(values.as_ptr().cast::<u8>(), std::mem::size_of_val(values))
        })
    }
    #[cfg(not(target_endian = "little"))]
    {
        let mut out = Vec::with_capacity(values.len() * 4);
        for v in values {
            out.extend_from_slice(&v.to_le_bytes());
        }
        Cow::Owned(out)
    }
}

/// The values of little-endian f32 bytes (`None` unless the length is a multiple of 4).
pub(crate) fn f32_from_le_bytes(bytes: &[u8]) -> Option<Vec<f32>> {
    if !bytes.len().is_multiple_of(4) {
        return None;
    }
    let n = bytes.len() / 4;
    #[cfg(target_endian = "little")]
    {
        let mut out: Vec<f32> = Vec::with_capacity(n);
        // SAFETY: `out` has capacity for `n` values, i.e. `4 * n == bytes.len()` bytes, and the
        // regions cannot overlap (`out` is freshly allocated); after the copy all `n` values are
        // initialised (any bit pattern is a valid `f32`), so `set_len(n)` is sound. On a
        // little-endian machine the wire bytes are the in-memory representation: one memcpy
        // instead of a per-value decode (and no zero-fill first).
        unsafe {
            std::ptr::copy_nonoverlapping(bytes.as_ptr(), out.as_mut_ptr().cast::<u8>(), 4 * n);
            out.set_len(n);
        }
        Some(out)
    }
    #[cfg(not(target_endian = "little"))]
    {
        Some(
            bytes
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect(),
        )
    }
}

struct F32Visitor;

impl<'de> Visitor<'de> for F32Visitor {
    type Value = Vec<f32>;

    fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("a byte string of little-endian f32 values")
    }

    fn visit_bytes<E: de::Error>(self, v: &[u8]) -> Result<Self::Value, E> {
        f32_from_le_bytes(v).ok_or_else(|| {
            E::custom(format_args!(
                "f32 column of {} bytes is not a multiple of 4",
                v.len()
            ))
        })
    }

    fn visit_borrowed_bytes<E: de::Error>(self, v: &'de [u8]) -> Result<Self::Value, E> {
        self.visit_bytes(v)
    }

    fn visit_byte_buf<E: de::Error>(self, v: Vec<u8>) -> Result<Self::Value, E> {
        self.visit_bytes(&v)
    }
}

/// Checks that every value is finite.
pub(crate) fn check_finite(field: &'static str, values: &[f32]) -> Result<(), ValidationError> {
    if all_finite(values) {
        return Ok(());
    }
    // Locate the culprit only when there is one.
    let index = values.iter().position(|v| !v.is_finite()).unwrap_or(0);
    Err(ValidationError::NonFinite { field, index })
}

/// Whether no value is NaN or infinite. Every message's float columns go through this on encode
/// and on decode, so it runs on AVX2 where the CPU has it (twice the lanes of the SSE2 baseline
/// the crate is compiled for).
fn all_finite(values: &[f32]) -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2, checked just above; the function has no other
            // precondition.
            return unsafe { all_finite_avx2(values) };
        }
    }
    all_finite_portable(values)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn all_finite_avx2(values: &[f32]) -> bool {
    all_finite_portable(values)
}

/// Branch-free on the bits (exponent all ones = NaN or infinity), so that it vectorises.
#[inline(always)]
fn all_finite_portable(values: &[f32]) -> bool {
    const EXP: u32 = 0x7f80_0000;
    values.chunks(256).all(|c| {
        c.iter()
            .fold(0u32, |bad, v| bad | u32::from(v.to_bits() & EXP == EXP))
            == 0
    })
}

/// Checks that a scalar is finite.
pub(crate) fn check_finite_f64(field: &'static str, value: f64) -> Result<(), ValidationError> {
    if value.is_finite() {
        Ok(())
    } else {
        Err(ValidationError::NonFinite { field, index: 0 })
    }
}

/// Checks `len == expected`.
pub(crate) fn check_len(
    field: &'static str,
    found: usize,
    expected: usize,
) -> Result<(), ValidationError> {
    if found == expected {
        Ok(())
    } else {
        Err(ValidationError::LengthMismatch {
            field,
            expected,
            found,
        })
    }
}

/// Checks `value <= limit`.
pub(crate) fn check_max(
    field: &'static str,
    value: u64,
    limit: u64,
) -> Result<(), ValidationError> {
    if value <= limit {
        Ok(())
    } else {
        Err(ValidationError::LimitExceeded {
            field,
            value,
            limit,
        })
    }
}

/// Checks a fraction in `[0, 1]`.
pub(crate) fn check_unit_interval(field: &'static str, value: f64) -> Result<(), ValidationError> {
    check_finite_f64(field, value)?;
    if (0.0..=1.0).contains(&value) {
        Ok(())
    } else {
        Err(ValidationError::InvalidField {
            field,
            reason: format!("{value} is not in [0, 1]"),
        })
    }
}

/// Checks a short identifier-like name: 1..=`max_len` bytes of `[a-z0-9_./-]`.
pub(crate) fn check_name(
    field: &'static str,
    name: &str,
    max_len: usize,
) -> Result<(), ValidationError> {
    let invalid = |reason: String| ValidationError::InvalidField { field, reason };
    if name.is_empty() {
        return Err(invalid("empty".into()));
    }
    if name.len() > max_len {
        return Err(invalid(format!(
            "{} bytes, longer than {max_len}",
            name.len()
        )));
    }
    if let Some(c) = name.chars().find(|c| {
        !(c.is_ascii_lowercase() || c.is_ascii_digit() || matches!(c, '_' | '.' | '/' | '-'))
    }) {
        return Err(invalid(format!(
            "character {c:?} not allowed (use [a-z0-9_./-])"
        )));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn finiteness_check_finds_every_non_finite_value() {
        for len in [0usize, 1, 7, 8, 9, 31, 255, 256, 257, 600] {
            let clean: Vec<f32> = (0..len).map(|i| i as f32 * -1.5e30).collect();
            assert!(all_finite(&clean) && all_finite_portable(&clean), "{len}");
            assert_eq!(check_finite("x", &clean), Ok(()));
            for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY, -f32::NAN] {
                for at in 0..len {
                    let mut v = clean.clone();
                    v[at] = bad;
                    assert!(!all_finite(&v) && !all_finite_portable(&v), "{len} {at}");
                    assert_eq!(
                        check_finite("x", &v),
                        Err(ValidationError::NonFinite {
                            field: "x",
                            index: at
                        })
                    );
                }
            }
        }
        // The largest finite values and subnormals are finite.
        let edge = [f32::MAX, f32::MIN, f32::MIN_POSITIVE / 2.0, -0.0];
        assert!(all_finite(&edge) && all_finite_portable(&edge));
    }
}
