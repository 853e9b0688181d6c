//! The MessagePack codec (rmp-serde, struct-map encoding).
//!
//! Episode batches, tens of thousands a second on one machine, take a hand-written path
//! (module `direct`) that writes and reads exactly serde's bytes; serde decodes whatever that
//! path does not take, so the format and the errors are serde's either way. [`prepare`] measures
//! such a message first, so that it can be encoded straight into a shared-memory sample.
//!
//! Every struct is encoded as a map keyed by field name (`rmp_serde`'s named encoding), so any
//! MessagePack library reads messages by field name; float columns are little-endian `bin`s
//! (see [`crate::columns`]). Decoding is bounded (size limit, nesting depth), checks the protocol
//! version and message kind, rejects trailing bytes and validates the body; every failure is a
//! [`DecodeError`].

use std::io;
use std::mem::MaybeUninit;

use serde::de::IgnoredAny;
use serde::{Deserialize, Serialize};

use crate::direct::{Reader, MAX_DEPTH};
use crate::error::{DecodeError, EncodeError, ValidationError};
use crate::header::{Body, Header, Message, MessageRef};
use crate::PROTOCOL_VERSION;

/// Default largest message accepted by [`decode`] and produced by [`encode`]: 16 MiB (SARL
/// weights are about 0.4 MB, an episode batch of 100 steps and 10 humans about 25 kB).
pub const DEFAULT_MAX_MESSAGE_BYTES: usize = 16 * 1024 * 1024;

/// Encodes `header` + `body` into a new buffer (validates both first).
pub fn encode<B: Body>(header: &Header, body: &B) -> Result<Vec<u8>, EncodeError> {
    let mut buf = Vec::new();
    encode_into(header, body, &mut buf, DEFAULT_MAX_MESSAGE_BYTES)?;
    Ok(buf)
}

/// Encodes a whole message (see [`encode`]).
pub fn encode_message<B: Body>(message: &Message<B>) -> Result<Vec<u8>, EncodeError> {
    encode(&message.header, &message.body)
}

/// Encodes into `buf` (cleared first, capacity reused), refusing encodings above `limit` bytes.
pub fn encode_into<B: Body>(
    header: &Header,
    body: &B,
    buf: &mut Vec<u8>,
    limit: usize,
) -> Result<(), EncodeError> {
    check_encodable(header, body)?;
    buf.clear();
    if !B::encode_direct(header, body, buf) {
        serde_encode(header, body, buf)?;
    }
    if buf.len() > limit {
        return Err(EncodeError::Oversized {
            len: buf.len(),
            limit,
        });
    }
    Ok(())
}

/// A validated message whose exact encoded length is known before it is written, so that it
/// can be encoded straight into memory the caller provides (a shared-memory sample) instead of
/// into a buffer that is then copied. See [`prepare`].
#[derive(Debug)]
pub struct Prepared<'a, B> {
    header: &'a Header,
    body: &'a B,
    len: usize,
}

impl<B: Body> Prepared<'_, B> {
    /// The exact number of bytes [`Prepared::write`] writes.
    pub fn encoded_len(&self) -> usize {
        self.len
    }

    /// Encodes the message into `out`, which must be exactly [`Prepared::encoded_len`] bytes
    /// long, and returns the now initialised bytes: the same bytes [`encode`] produces.
    pub fn write<'o>(&self, out: &'o mut [MaybeUninit<u8>]) -> Result<&'o mut [u8], EncodeError> {
        if out.len() != self.len || !B::direct_write(self.header, self.body, out) {
            return Err(EncodeError::Serialize(format!(
                "a destination of {} bytes for a message of {} bytes",
                out.len(),
                self.len
            )));
        }
        // SAFETY: `direct_write` returned true, so it wrote every one of the `out.len()` bytes
        // (see `Body::direct_write`); `MaybeUninit<u8>` has the layout of `u8`, and the
        // returned slice takes over `out`'s unique borrow.
        Ok(unsafe { std::slice::from_raw_parts_mut(out.as_mut_ptr().cast::<u8>(), out.len()) })
    }
}

/// Validates `header` + `body` (as [`encode_into`] does) and measures the encoding, for messages
/// with a hand-written codec (episode batches); `Ok(None)` for the others, which encode with
/// [`encode_into`].
pub fn prepare<'a, B: Body>(
    header: &'a Header,
    body: &'a B,
    limit: usize,
) -> Result<Option<Prepared<'a, B>>, EncodeError> {
    let Some(len) = B::direct_len(header, body) else {
        return Ok(None);
    };
    check_encodable(header, body)?;
    if len > limit {
        return Err(EncodeError::Oversized { len, limit });
    }
    Ok(Some(Prepared { header, body, len }))
}

fn check_encodable<B: Body>(header: &Header, body: &B) -> Result<(), EncodeError> {
    if header.kind != B::KIND {
        return Err(ValidationError::InvalidField {
            field: "header.kind",
            reason: format!("header says {}, body is {}", header.kind, B::KIND),
        }
        .into());
    }
    Ok(body.validate()?)
}

fn serde_encode<B: Body>(header: &Header, body: &B, buf: &mut Vec<u8>) -> Result<(), EncodeError> {
    let mut ser = rmp_serde::Serializer::new(&mut *buf).with_struct_map();
    MessageRef { header, body }
        .serialize(&mut ser)
        .map_err(|e| EncodeError::Serialize(e.to_string()))
}

/// Decodes and validates a message of type `B` no larger than [`DEFAULT_MAX_MESSAGE_BYTES`].
pub fn decode<B: Body>(bytes: &[u8]) -> Result<Message<B>, DecodeError> {
    decode_with_limit(bytes, DEFAULT_MAX_MESSAGE_BYTES)
}

/// Decodes and validates a message of type `B` no larger than `limit` bytes.
pub fn decode_with_limit<B: Body>(bytes: &[u8], limit: usize) -> Result<Message<B>, DecodeError> {
    decode_checked(bytes, limit, true)
}

/// [`decode_with_limit`] through serde alone, never the hand-written decoder of
/// [`Body::decode_direct`]: the reference the tests compare that decoder with.
#[doc(hidden)]
pub fn decode_with_limit_serde<B: Body>(
    bytes: &[u8],
    limit: usize,
) -> Result<Message<B>, DecodeError> {
    decode_checked(bytes, limit, false)
}

fn decode_checked<B: Body>(
    bytes: &[u8],
    limit: usize,
    direct: bool,
) -> Result<Message<B>, DecodeError> {
    if bytes.len() > limit {
        return Err(DecodeError::Oversized {
            len: bytes.len(),
            limit,
        });
    }
    if bytes.is_empty() {
        return Err(DecodeError::Truncated);
    }
    // The hand-written decoder takes the common case; serde decodes (and explains) the rest.
    let message = match direct.then(|| B::decode_direct(bytes)).flatten() {
        Some(m) => m,
        None => serde_decode(bytes)?,
    };
    let header = &message.header;
    if header.protocol_version != PROTOCOL_VERSION {
        return Err(DecodeError::WrongProtocolVersion {
            found: header.protocol_version,
            expected: PROTOCOL_VERSION,
        });
    }
    if header.kind != B::KIND {
        return Err(DecodeError::WrongKind {
            expected: B::KIND,
            found: header.kind,
        });
    }
    message.body.validate()?;
    Ok(message)
}

/// The message's structure through serde, with no bytes left over.
fn serde_decode<B: Body>(bytes: &[u8]) -> Result<Message<B>, DecodeError> {
    let mut de = rmp_serde::Deserializer::from_read_ref(bytes);
    de.set_max_depth(MAX_DEPTH);
    let message = match Message::<B>::deserialize(&mut de) {
        Ok(m) => m,
        Err(e) => {
            // Tell "another protocol version" apart from garbage before reporting the error.
            if let Some(found) = probe_protocol_version(bytes) {
                if found != PROTOCOL_VERSION {
                    return Err(DecodeError::WrongProtocolVersion {
                        found,
                        expected: PROTOCOL_VERSION,
                    });
                }
            }
            return Err(map_rmp_error(e));
        }
    };
    // Anything after the message? Reading one more value must hit the end of input.
    match IgnoredAny::deserialize(&mut de) {
        Err(rmp_serde::decode::Error::InvalidMarkerRead(e))
            if e.kind() == io::ErrorKind::UnexpectedEof => {}
        _ => {
            let consumed = consumed_len(bytes).unwrap_or(0);
            return Err(DecodeError::TrailingBytes(
                bytes.len().saturating_sub(consumed).max(1),
            ));
        }
    }
    Ok(message)
}

/// Reads only the protocol version of an encoded message, if it can be found. Cheap; never
/// panics. Useful for logging rejected messages.
pub fn probe_protocol_version(bytes: &[u8]) -> Option<u16> {
    let header = Reader::new(bytes).field(0, "header")?;
    let version = Reader::new(header).field(0, "protocol_version")?;
    u16::try_from(Reader::new(version).uint()?).ok()
}

fn map_rmp_error(e: rmp_serde::decode::Error) -> DecodeError {
    use rmp_serde::decode::Error as E;
    match e {
        E::InvalidMarkerRead(io) | E::InvalidDataRead(io)
            if io.kind() == io::ErrorKind::UnexpectedEof =>
        {
            DecodeError::Truncated
        }
        // Validation inside deserialisers (run ids, f32 columns) and type errors.
        other => DecodeError::Malformed(other.to_string()),
    }
}

fn consumed_len(bytes: &[u8]) -> Option<usize> {
    let mut r = Reader::new(bytes);
    r.skip(0)?;
    Some(r.pos())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reader_skips_nested_values() {
        let v = (1u8, "ab", vec![1.5f64, 2.0], (true, ()));
        let bytes = rmp_serde::to_vec(&v).expect("encode");
        assert_eq!(consumed_len(&bytes), Some(bytes.len()));
        let mut with_tail = bytes.clone();
        with_tail.push(0x01);
        assert_eq!(consumed_len(&with_tail), Some(bytes.len()));
        assert_eq!(consumed_len(&bytes[..bytes.len() - 1]), None);
    }
}
