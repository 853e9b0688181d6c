//! The bytes of an event file: TFRecord framing (length, masked CRC-32C of the length, data,
//! masked CRC-32C of the data) around `tensorflow.Event` protobuf messages, of which fsrl writes
//! three kinds: the file version, a scalar summary, and a session start (which tells a running
//! TensorBoard to forget what it read at and after that step: a rebuilt file, see
//! [`crate::board`]).
//!
//! The fields written, from `tensorflow/core/util/event.proto` and `summary.proto`:
//! `Event { double wall_time = 1; int64 step = 2; string file_version = 3; Summary summary = 5;
//! SessionLog session_log = 7; }` (not 6, the deprecated `LogMessage`: a session start written
//! there was read as a log message, and TensorBoard forgot nothing), `Summary { repeated Value
//! value = 1; }`,
//! `Summary.Value { string tag = 1; float simple_value = 2; }`,
//! `SessionLog { SessionStatus status = 1; }` with `START = 1`. Reading skips every other field.

use crate::crc32c::masked;

/// One scalar point: a tag's value at a step (RL episodes, or imitation epochs on their own
/// tags), with the Unix time it was written.
#[derive(Debug, Clone, PartialEq)]
pub struct Scalar {
    pub tag: String,
    pub step: i64,
    pub value: f32,
    pub wall_time: f64,
}

/// What an event holds, as far as fsrl reads it.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Event {
    pub wall_time: f64,
    pub step: i64,
    pub file_version: Option<String>,
    /// `(tag, simple_value)` of the summary's values that have one.
    pub values: Vec<(String, f32)>,
    pub session_start: bool,
}

/// The version string TensorBoard expects in the first event (version 2: restarts are marked
/// by session-log events, not guessed from steps going backwards).
pub const FILE_VERSION: &str = "brain.Event:2";

fn varint(out: &mut Vec<u8>, mut v: u64) {
    while v >= 0x80 {
        out.push((v as u8) | 0x80);
        v >>= 7;
    }
    out.push(v as u8);
}

fn key(out: &mut Vec<u8>, field: u32, wire: u8) {
    varint(out, ((field as u64) << 3) | wire as u64);
}

fn bytes_field(out: &mut Vec<u8>, field: u32, b: &[u8]) {
    key(out, field, 2);
    varint(out, b.len() as u64);
    out.extend_from_slice(b);
}

fn head(wall_time: f64, step: i64) -> Vec<u8> {
    let mut out = Vec::with_capacity(64);
    key(&mut out, 1, 1);
    out.extend_from_slice(&wall_time.to_le_bytes());
    if step != 0 {
        key(&mut out, 2, 0);
        varint(&mut out, step as u64);
    }
    out
}

/// The file-version event that opens every event file.
pub fn file_version(wall_time: f64) -> Vec<u8> {
    let mut out = head(wall_time, 0);
    bytes_field(&mut out, 3, FILE_VERSION.as_bytes());
    out
}

/// A scalar summary event.
pub fn scalar(s: &Scalar) -> Vec<u8> {
    let mut value = Vec::with_capacity(s.tag.len() + 8);
    bytes_field(&mut value, 1, s.tag.as_bytes());
    key(&mut value, 2, 5);
    value.extend_from_slice(&s.value.to_le_bytes());
    let mut summary = Vec::with_capacity(value.len() + 4);
    bytes_field(&mut summary, 1, &value);
    let mut out = head(s.wall_time, s.step);
    bytes_field(&mut out, 5, &summary);
    out
}

/// A session-start event at `step`.
pub fn session_start(wall_time: f64, step: i64) -> Vec<u8> {
    let mut log = Vec::new();
    key(&mut log, 1, 0);
    varint(&mut log, 1);
    let mut out = head(wall_time, step);
    bytes_field(&mut out, 7, &log);
    out
}

/// Appends `data` framed as one TFRecord.
pub fn frame(out: &mut Vec<u8>, data: &[u8]) {
    let len = (data.len() as u64).to_le_bytes();
    out.extend_from_slice(&len);
    out.extend_from_slice(&masked(&len).to_le_bytes());
    out.extend_from_slice(data);
    out.extend_from_slice(&masked(data).to_le_bytes());
}

/// The records of `bytes`, up to the first one that is torn or fails its checksums (a file
/// being written, or cut by a crash): the records and the length of the good prefix.
pub fn records(bytes: &[u8]) -> (Vec<&[u8]>, usize) {
    let mut out = Vec::new();
    let mut at = 0;
    while bytes.len() - at >= 12 {
        let len_bytes = &bytes[at..at + 8];
        let crc = u32::from_le_bytes(bytes[at + 8..at + 12].try_into().expect("4 bytes"));
        if masked(len_bytes) != crc {
            break;
        }
        let len = u64::from_le_bytes(len_bytes.try_into().expect("8 bytes"));
        let Some(end) = usize::try_from(len)
            .ok()
            .and_then(|l| (at + 12).checked_add(l))
            .filter(|&e| e.checked_add(4).is_some_and(|e4| e4 <= bytes.len()))
        else {
            break;
        };
        let data = &bytes[at + 12..end];
        let crc = u32::from_le_bytes(bytes[end..end + 4].try_into().expect("4 bytes"));
        if masked(data) != crc {
            break;
        }
        out.push(data);
        at = end + 4;
    }
    (out, at)
}

/// A protobuf reader over one message's bytes.
struct Reader<'a> {
    b: &'a [u8],
}

impl<'a> Reader<'a> {
    fn varint(&mut self) -> Option<u64> {
        let mut v = 0u64;
        for shift in (0..64).step_by(7) {
            let (&byte, rest) = self.b.split_first()?;
            self.b = rest;
            v |= ((byte & 0x7f) as u64) << shift;
            if byte & 0x80 == 0 {
                return Some(v);
            }
        }
        None
    }

    fn take(&mut self, n: usize) -> Option<&'a [u8]> {
        if self.b.len() < n {
            return None;
        }
        let (a, rest) = self.b.split_at(n);
        self.b = rest;
        Some(a)
    }

    /// The next field: its number and value (a varint, 8 bytes, bytes or 4 bytes).
    fn field(&mut self) -> Option<(u32, Field<'a>)> {
        let k = self.varint()?;
        let f = match k & 7 {
            0 => Field::Varint(self.varint()?),
            1 => Field::Fixed64(self.take(8)?.try_into().ok()?),
            2 => {
                let n = usize::try_from(self.varint()?).ok()?;
                Field::Bytes(self.take(n)?)
            }
            5 => Field::Fixed32(self.take(4)?.try_into().ok()?),
            _ => return None,
        };
        Some(((k >> 3) as u32, f))
    }

    fn fields(mut self) -> Option<Vec<(u32, Field<'a>)>> {
        let mut out = Vec::new();
        while !self.b.is_empty() {
            out.push(self.field()?);
        }
        Some(out)
    }
}

enum Field<'a> {
    Varint(u64),
    Fixed64([u8; 8]),
    Bytes(&'a [u8]),
    Fixed32([u8; 4]),
}

/// Reads one event; `None` if the bytes are not a well-formed protobuf message.
pub fn decode(data: &[u8]) -> Option<Event> {
    let mut e = Event::default();
    for (n, f) in (Reader { b: data }).fields()? {
        match (n, f) {
            (1, Field::Fixed64(b)) => e.wall_time = f64::from_le_bytes(b),
            (2, Field::Varint(v)) => e.step = v as i64,
            (3, Field::Bytes(b)) => e.file_version = Some(String::from_utf8_lossy(b).into()),
            (5, Field::Bytes(summary)) => {
                for (n, f) in (Reader { b: summary }).fields()? {
                    let (1, Field::Bytes(value)) = (n, f) else {
                        continue;
                    };
                    let (mut tag, mut simple) = (None, None);
                    for (n, f) in (Reader { b: value }).fields()? {
                        match (n, f) {
                            (1, Field::Bytes(t)) => tag = Some(String::from_utf8_lossy(t).into()),
                            (2, Field::Fixed32(v)) => simple = Some(f32::from_le_bytes(v)),
                            _ => {}
                        }
                    }
                    if let (Some(t), Some(v)) = (tag, simple) {
                        e.values.push((t, v));
                    }
                }
            }
            (7, Field::Bytes(log)) => {
                for (n, f) in (Reader { b: log }).fields()? {
                    if let (1, Field::Varint(1)) = (n, f) {
                        e.session_start = true;
                    }
                }
            }
            _ => {}
        }
    }
    Some(e)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_scalar_event_has_protobufs_bytes() {
        // Written by hand from the wire format: wall_time 1.5, step 300, tag "a/b", value 0.25.
        let s = Scalar {
            tag: "a/b".into(),
            step: 300,
            value: 0.25,
            wall_time: 1.5,
        };
        let mut want = vec![0x09];
        want.extend_from_slice(&1.5f64.to_le_bytes());
        want.extend_from_slice(&[0x10, 0xac, 0x02]); // step 300 as a varint
        want.extend_from_slice(&[0x2a, 12, 0x0a, 10, 0x0a, 3, b'a', b'/', b'b', 0x15]);
        want.extend_from_slice(&0.25f32.to_le_bytes());
        assert_eq!(scalar(&s), want);
        let e = decode(&want).unwrap();
        assert_eq!((e.wall_time, e.step), (1.5, 300));
        assert_eq!(e.values, vec![("a/b".to_string(), 0.25)]);
    }

    #[test]
    fn version_and_session_events_round_trip() {
        let e = decode(&file_version(7.0)).unwrap();
        assert_eq!(e.file_version.as_deref(), Some(FILE_VERSION));
        assert!(!e.session_start);
        // Event field 7 (session_log), a SessionLog of status START: protobuf's own bytes.
        let start = session_start(8.0, 0);
        let want = [&[0x09][..], &8.0f64.to_le_bytes(), &[0x3a, 2, 0x08, 1]].concat();
        assert_eq!(start, want);
        let e = decode(&start).unwrap();
        assert!(e.session_start && e.values.is_empty());
        assert_eq!(e.wall_time, 8.0);
    }

    #[test]
    fn records_stop_at_a_torn_or_corrupt_tail() {
        let mut f = Vec::new();
        frame(&mut f, b"first");
        frame(&mut f, b"second");
        let whole = f.len();
        let (r, good) = records(&f);
        assert_eq!(r, vec![&b"first"[..], &b"second"[..]]);
        assert_eq!(good, whole);
        // A record cut short: the first stays.
        let (r, good) = records(&f[..whole - 3]);
        assert_eq!(r, vec![&b"first"[..]]);
        assert_eq!(good, 8 + 4 + 5 + 4);
        // A flipped data byte fails the data's checksum; a flipped length byte the length's.
        let mut bad = f.clone();
        bad[12] ^= 1;
        assert!(records(&bad).0.is_empty());
        let mut bad = f.clone();
        bad[0] ^= 1;
        assert!(records(&bad).0.is_empty());
    }

    #[test]
    fn garbage_never_panics() {
        let mut x = 0x1234_5678u32;
        for n in 0..2000 {
            let b: Vec<u8> = (0..n % 64)
                .map(|_| {
                    x ^= x << 13;
                    x ^= x >> 17;
                    x ^= x << 5;
                    x as u8
                })
                .collect();
            let _ = decode(&b);
            let _ = records(&b);
        }
    }
}
