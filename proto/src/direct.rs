//! Hand-written MessagePack for the hot message: [`TransitionBatch`] (actor → learner, tens of
//! thousands per second on one machine).
//!
//! The bytes are exactly those of the serde encoding in [`crate::codec`] (named fields, float
//! columns as `bin`), so nothing changes on the wire and other languages read them as before;
//! only serde's per-field dispatch, per-element decoding of small arrays and the intermediate
//! `String`s of the header are skipped. Tests check both directions against serde
//! (`proto/tests/proto/direct.rs`): the encoder byte for byte, the decoder on valid messages and
//! on well over 100 000 corrupted ones.
//!
//! The decoder reads only the layout the encoder writes (fields in declaration order, canonical
//! markers). Anything else, valid or not (another encoder's field order, a truncation, a bad
//! marker), makes it give up with `None`, and [`crate::codec`] decodes the bytes with serde,
//! which accepts every valid layout and names the error of an invalid one. So the fast path can
//! only ever return what serde would have returned.

use std::mem::MaybeUninit;

use crate::error::ValidationError;
use crate::header::{Body, Header, Message, MessageKind};
use crate::ids::{Role, RunId, SenderId};
use crate::transitions::{Outcome, TransitionBatch};

/// Nesting depth accepted when decoding, here and by serde in [`crate::codec`] (our messages
/// nest at most 4 levels).
pub(crate) const MAX_DEPTH: usize = 32;

/// A batch is a [`Body`] whose encoding and decoding try the hand-written path of this module
/// first; its checks are `TransitionBatch::check`, in `transitions.rs`.
impl Body for TransitionBatch {
    const KIND: MessageKind = MessageKind::TransitionBatch;

    fn encode_direct(header: &Header, body: &Self, buf: &mut Vec<u8>) -> bool {
        buf.reserve(body.approx_encoded_len());
        encode_batch(header, body, buf);
        true
    }

    fn direct_len(header: &Header, body: &Self) -> Option<usize> {
        let mut n = Counter(0);
        encode_batch(header, body, &mut n);
        Some(n.0)
    }

    fn direct_write(header: &Header, body: &Self, out: &mut [MaybeUninit<u8>]) -> bool {
        let mut w = Uninit::new(out);
        encode_batch(header, body, &mut w);
        w.filled()
    }

    fn decode_direct(bytes: &[u8]) -> Option<Message<Self>> {
        decode_batch(bytes)
    }

    fn validate(&self) -> Result<(), ValidationError> {
        self.check()
    }
}

// ---------------------------------------------------------------------------------------------
// Writing (the same marker choices as rmp: the smallest that holds the value or length), into
// any [`Sink`]: a `Vec`, a length counter, or caller-provided memory such as a shared-memory
// sample. The length and the bytes come from the same code, so they always agree.

/// Where encoded bytes go.
pub(crate) trait Sink {
    fn put(&mut self, bytes: &[u8]);
    #[inline(always)]
    fn push(&mut self, byte: u8) {
        self.put(&[byte]);
    }
}

impl Sink for Vec<u8> {
    #[inline(always)]
    fn put(&mut self, bytes: &[u8]) {
        self.extend_from_slice(bytes);
    }
    #[inline(always)]
    fn push(&mut self, byte: u8) {
        Vec::push(self, byte);
    }
}

/// Counts the bytes an encoding takes.
pub(crate) struct Counter(pub(crate) usize);

impl Sink for Counter {
    #[inline(always)]
    fn put(&mut self, bytes: &[u8]) {
        self.0 += bytes.len();
    }
}

/// Fills uninitialised memory from the start; remembers an overflow instead of writing past
/// the end.
pub(crate) struct Uninit<'a> {
    out: &'a mut [MaybeUninit<u8>],
    pos: usize,
    overflow: bool,
}

impl<'a> Uninit<'a> {
    pub(crate) fn new(out: &'a mut [MaybeUninit<u8>]) -> Self {
        Self {
            out,
            pos: 0,
            overflow: false,
        }
    }

    /// Whether every byte of the memory was written, and nothing more was attempted.
    pub(crate) fn filled(&self) -> bool {
        !self.overflow && self.pos == self.out.len()
    }
}

impl Sink for Uninit<'_> {
    #[inline(always)]
    fn put(&mut self, bytes: &[u8]) {
        let end = self.pos + bytes.len();
        match self.out.get_mut(self.pos..end) {
            Some(dst) => {
                // SAFETY: `dst` is exactly `bytes.len()` elements of writable memory, and a
                // `MaybeUninit<u8>` has the layout of a `u8`; `bytes` is borrowed immutably
                // while `dst` is a unique borrow, so the two cannot overlap.
                unsafe {
                    std::ptr::copy_nonoverlapping(
                        bytes.as_ptr(),
                        dst.as_mut_ptr().cast::<u8>(),
                        bytes.len(),
                    );
                }
                self.pos = end;
            }
            None => self.overflow = true,
        }
    }
}

#[inline]
fn put_len(w: &mut impl Sink, n: usize, fix_base: u8, fix_max: usize, m8: Option<u8>, m16: u8) {
    let m32 = m16 + 1;
    if n <= fix_max {
        w.push(fix_base | n as u8);
    } else if let (Some(m8), true) = (m8, n <= 0xff) {
        w.put(&[m8, n as u8]);
    } else if n <= 0xffff {
        w.push(m16);
        w.put(&(n as u16).to_be_bytes());
    } else {
        w.push(m32);
        w.put(&(n as u32).to_be_bytes());
    }
}

#[inline]
fn put_map(w: &mut impl Sink, n: usize) {
    put_len(w, n, 0x80, 15, None, 0xde);
}

#[inline]
fn put_array(w: &mut impl Sink, n: usize) {
    put_len(w, n, 0x90, 15, None, 0xdc);
}

#[inline(always)]
fn put_str(w: &mut impl Sink, s: &str) {
    put_len(w, s.len(), 0xa0, 31, Some(0xd9), 0xda);
    w.put(s.as_bytes());
}

#[inline]
fn put_bin(w: &mut impl Sink, b: &[u8]) {
    // bin has no fix form: bin8 (0xc4), bin16 (0xc5), bin32 (0xc6).
    if b.len() <= 0xff {
        w.put(&[0xc4, b.len() as u8]);
    } else if b.len() <= 0xffff {
        w.push(0xc5);
        w.put(&(b.len() as u16).to_be_bytes());
    } else {
        w.push(0xc6);
        w.put(&(b.len() as u32).to_be_bytes());
    }
    w.put(b);
}

#[inline(always)]
fn put_uint(w: &mut impl Sink, v: u64) {
    if v < 0x80 {
        w.push(v as u8);
    } else if v <= 0xff {
        w.put(&[0xcc, v as u8]);
    } else if v <= 0xffff {
        w.push(0xcd);
        w.put(&(v as u16).to_be_bytes());
    } else if v <= 0xffff_ffff {
        w.push(0xce);
        w.put(&(v as u32).to_be_bytes());
    } else {
        w.push(0xcf);
        w.put(&v.to_be_bytes());
    }
}

#[inline(always)]
fn put_bool(w: &mut impl Sink, v: bool) {
    w.push(if v { 0xc3 } else { 0xc2 });
}

#[inline]
fn put_f32(w: &mut impl Sink, v: f32) {
    w.push(0xca);
    w.put(&v.to_be_bytes());
}

#[inline]
fn put_f32_column(w: &mut impl Sink, values: &[f32]) {
    put_bin(w, &crate::columns::f32_le_bytes(values));
}

fn put_header(w: &mut impl Sink, h: &Header) {
    put_map(w, 6);
    put_str(w, "protocol_version");
    put_uint(w, h.protocol_version.into());
    put_str(w, "kind");
    put_str(w, h.kind.as_str());
    put_str(w, "run");
    put_str(w, h.run.as_str());
    put_str(w, "sender");
    put_map(w, 2);
    put_str(w, "role");
    put_str(w, h.sender.role.as_str());
    put_str(w, "index");
    put_uint(w, h.sender.index.into());
    put_str(w, "seq");
    put_uint(w, h.seq);
    put_str(w, "policy_version");
    put_uint(w, h.policy_version);
}

fn outcome_name(o: Outcome) -> &'static str {
    match o {
        Outcome::Running => "Running",
        Outcome::Collision => "Collision",
        Outcome::ReachGoal => "ReachGoal",
        Outcome::Timeout => "Timeout",
    }
}

/// Writes the message `{header, body}` (the caller validates first).
pub(crate) fn encode_batch(header: &Header, b: &TransitionBatch, w: &mut impl Sink) {
    put_map(w, 2);
    put_str(w, "header");
    put_header(w, header);
    put_str(w, "body");
    put_map(w, 17);
    put_str(w, "setting");
    put_str(w, &b.setting);
    put_str(w, "seed");
    put_uint(w, b.seed);
    put_str(w, "episode");
    put_uint(w, b.episode);
    put_str(w, "chunk");
    put_uint(w, b.chunk.into());
    put_str(w, "last_chunk");
    put_bool(w, b.last_chunk);
    put_str(w, "first_step");
    put_uint(w, b.first_step.into());
    put_str(w, "n_steps");
    put_uint(w, b.n_steps.into());
    put_str(w, "n_humans");
    put_uint(w, b.n_humans.into());
    put_str(w, "n_actions");
    put_uint(w, b.n_actions.into());
    put_str(w, "epsilon");
    put_f32(w, b.epsilon);
    put_str(w, "human_standing");
    put_array(w, b.human_standing.len());
    for s in &b.human_standing {
        put_bool(w, *s);
    }
    put_str(w, "robot_states");
    put_f32_column(w, &b.robot_states);
    put_str(w, "human_states");
    put_f32_column(w, &b.human_states);
    put_str(w, "actions");
    put_array(w, b.actions.len());
    for a in &b.actions {
        put_uint(w, (*a).into());
    }
    put_str(w, "rewards");
    put_f32_column(w, &b.rewards);
    put_str(w, "closest_dist_m");
    put_f32_column(w, &b.closest_dist_m);
    put_str(w, "outcome");
    put_str(w, outcome_name(b.outcome));
}

// ---------------------------------------------------------------------------------------------
// Reading: `None` whenever the input is not exactly what `encode_batch` writes. The reader is
// bounds-checked throughout; `codec` also uses it to probe messages serde rejected.

pub(crate) struct Reader<'a> {
    buf: &'a [u8],
    pos: usize,
}

impl<'a> Reader<'a> {
    pub(crate) fn new(buf: &'a [u8]) -> Self {
        Self { buf, pos: 0 }
    }

    /// Bytes read so far.
    pub(crate) fn pos(&self) -> usize {
        self.pos
    }

    fn take(&mut self, n: usize) -> Option<&'a [u8]> {
        let end = self.pos.checked_add(n)?;
        let s = self.buf.get(self.pos..end)?;
        self.pos = end;
        Some(s)
    }

    fn byte(&mut self) -> Option<u8> {
        let b = *self.buf.get(self.pos)?;
        self.pos += 1;
        Some(b)
    }

    fn be<const N: usize>(&mut self) -> Option<[u8; N]> {
        self.take(N)?.try_into().ok()
    }

    fn be_len(&mut self, n: usize) -> Option<usize> {
        Some(match n {
            1 => usize::from(self.byte()?),
            2 => usize::from(u16::from_be_bytes(self.be()?)),
            _ => usize::try_from(u32::from_be_bytes(self.be()?)).ok()?,
        })
    }

    fn map_len(&mut self) -> Option<usize> {
        match self.byte()? {
            m @ 0x80..=0x8f => Some(usize::from(m & 0x0f)),
            0xde => self.be_len(2),
            0xdf => self.be_len(4),
            _ => None,
        }
    }

    fn array_len(&mut self) -> Option<usize> {
        match self.byte()? {
            m @ 0x90..=0x9f => Some(usize::from(m & 0x0f)),
            0xdc => self.be_len(2),
            0xdd => self.be_len(4),
            _ => None,
        }
    }

    fn str_bytes(&mut self) -> Option<&'a [u8]> {
        let n = match self.byte()? {
            m @ 0xa0..=0xbf => usize::from(m & 0x1f),
            0xd9 => self.be_len(1)?,
            0xda => self.be_len(2)?,
            0xdb => self.be_len(4)?,
            _ => return None,
        };
        self.take(n)
    }

    fn str(&mut self) -> Option<&'a str> {
        std::str::from_utf8(self.str_bytes()?).ok()
    }

    /// The next value must be the string `name` (a field key). Inlined, so that the comparison
    /// is one of a known length at each call site.
    #[inline(always)]
    fn key(&mut self, name: &str) -> Option<()> {
        (self.str_bytes()? == name.as_bytes()).then_some(())
    }

    fn bin(&mut self) -> Option<&'a [u8]> {
        let n = match self.byte()? {
            0xc4 => self.be_len(1)?,
            0xc5 => self.be_len(2)?,
            0xc6 => self.be_len(4)?,
            _ => return None,
        };
        self.take(n)
    }

    /// A container header: `(is_map, number of entries)`.
    fn container(&mut self) -> Option<(bool, usize)> {
        match *self.buf.get(self.pos)? {
            0x80..=0x8f | 0xde | 0xdf => Some((true, self.map_len()?)),
            0x90..=0x9f | 0xdc | 0xdd => Some((false, self.array_len()?)),
            _ => None,
        }
    }

    /// The raw bytes of field `name` of a struct encoded as a map, or of element `index` of a
    /// struct encoded as an array (any field order, any value types).
    pub(crate) fn field(&mut self, index: usize, name: &str) -> Option<&'a [u8]> {
        let (is_map, len) = self.container()?;
        for i in 0..len {
            let is_it = if is_map {
                self.str_bytes()? == name.as_bytes()
            } else {
                i == index
            };
            let start = self.pos;
            self.skip(1)?;
            if is_it {
                return self.buf.get(start..self.pos);
            }
        }
        None
    }

    /// Skips one value of any type (found at nesting level `depth`; at most
    /// [`MAX_DEPTH`] levels).
    pub(crate) fn skip(&mut self, depth: usize) -> Option<()> {
        if depth > MAX_DEPTH {
            return None;
        }
        let m = self.byte()?;
        let (items, bytes): (usize, usize) = match m {
            0x00..=0x7f | 0xe0..=0xff | 0xc0 | 0xc2 | 0xc3 => (0, 0),
            0x80..=0x8f => (2 * usize::from(m & 0x0f), 0),
            0x90..=0x9f => (usize::from(m & 0x0f), 0),
            0xa0..=0xbf => (0, usize::from(m & 0x1f)),
            0xc4 | 0xd9 => (0, self.be_len(1)?),
            0xc5 | 0xda => (0, self.be_len(2)?),
            0xc6 | 0xdb => (0, self.be_len(4)?),
            0xc7 => (0, self.be_len(1)?.checked_add(1)?),
            0xc8 => (0, self.be_len(2)?.checked_add(1)?),
            0xc9 => (0, self.be_len(4)?.checked_add(1)?),
            0xca => (0, 4),
            0xcb => (0, 8),
            0xcc | 0xd0 => (0, 1),
            0xcd | 0xd1 => (0, 2),
            0xce | 0xd2 => (0, 4),
            0xcf | 0xd3 => (0, 8),
            0xd4 => (0, 2),
            0xd5 => (0, 3),
            0xd6 => (0, 5),
            0xd7 => (0, 9),
            0xd8 => (0, 17),
            0xdc => (self.be_len(2)?, 0),
            0xdd => (self.be_len(4)?, 0),
            0xde => (self.be_len(2)?.checked_mul(2)?, 0),
            0xdf => (self.be_len(4)?.checked_mul(2)?, 0),
            0xc1 => return None,
        };
        self.take(bytes)?;
        for _ in 0..items {
            self.skip(depth + 1)?;
        }
        Some(())
    }

    pub(crate) fn uint(&mut self) -> Option<u64> {
        Some(match self.byte()? {
            m @ 0x00..=0x7f => u64::from(m),
            0xcc => u64::from(self.byte()?),
            0xcd => u64::from(u16::from_be_bytes(self.be()?)),
            0xce => u64::from(u32::from_be_bytes(self.be()?)),
            0xcf => u64::from_be_bytes(self.be()?),
            _ => return None,
        })
    }

    fn u32(&mut self) -> Option<u32> {
        u32::try_from(self.uint()?).ok()
    }

    fn u16(&mut self) -> Option<u16> {
        u16::try_from(self.uint()?).ok()
    }

    fn bool(&mut self) -> Option<bool> {
        match self.byte()? {
            0xc2 => Some(false),
            0xc3 => Some(true),
            _ => None,
        }
    }

    fn f32(&mut self) -> Option<f32> {
        match self.byte()? {
            0xca => Some(f32::from_be_bytes(self.be()?)),
            _ => None,
        }
    }

    fn f32_column(&mut self) -> Option<Vec<f32>> {
        crate::columns::f32_from_le_bytes(self.bin()?)
    }

    fn header(&mut self) -> Option<Header> {
        (self.map_len()? == 6).then_some(())?;
        self.key("protocol_version")?;
        let protocol_version = self.u16()?;
        self.key("kind")?;
        // Only the kind this decoder is for; serde handles (and reports) any other.
        (self.str_bytes()? == MessageKind::TransitionBatch.as_str().as_bytes()).then_some(())?;
        self.key("run")?;
        let run = RunId::new(self.str()?).ok()?;
        self.key("sender")?;
        (self.map_len()? == 2).then_some(())?;
        self.key("role")?;
        let role = self.str()?;
        let role = Role::ALL.into_iter().find(|r| r.as_str() == role)?;
        self.key("index")?;
        let index = self.u32()?;
        self.key("seq")?;
        let seq = self.uint()?;
        self.key("policy_version")?;
        let policy_version = self.uint()?;
        Some(Header {
            protocol_version,
            kind: MessageKind::TransitionBatch,
            run,
            sender: SenderId::new(role, index),
            seq,
            policy_version,
        })
    }

    fn batch(&mut self) -> Option<TransitionBatch> {
        (self.map_len()? == 17).then_some(())?;
        self.key("setting")?;
        let setting = self.str()?.to_owned();
        self.key("seed")?;
        let seed = self.uint()?;
        self.key("episode")?;
        let episode = self.uint()?;
        self.key("chunk")?;
        let chunk = self.u32()?;
        self.key("last_chunk")?;
        let last_chunk = self.bool()?;
        self.key("first_step")?;
        let first_step = self.u32()?;
        self.key("n_steps")?;
        let n_steps = self.u32()?;
        self.key("n_humans")?;
        let n_humans = self.u32()?;
        self.key("n_actions")?;
        let n_actions = self.u16()?;
        self.key("epsilon")?;
        let epsilon = self.f32()?;
        self.key("human_standing")?;
        let n = self.array_len()?;
        // Each element takes at least one byte: a length beyond the input is a truncation.
        (n <= self.buf.len() - self.pos).then_some(())?;
        let mut human_standing = Vec::with_capacity(n);
        for _ in 0..n {
            human_standing.push(self.bool()?);
        }
        self.key("robot_states")?;
        let robot_states = self.f32_column()?;
        self.key("human_states")?;
        let human_states = self.f32_column()?;
        self.key("actions")?;
        let n = self.array_len()?;
        (n <= self.buf.len() - self.pos).then_some(())?;
        let mut actions = Vec::with_capacity(n);
        for _ in 0..n {
            actions.push(self.u16()?);
        }
        self.key("rewards")?;
        let rewards = self.f32_column()?;
        self.key("closest_dist_m")?;
        let closest_dist_m = self.f32_column()?;
        self.key("outcome")?;
        let outcome = match self.str_bytes()? {
            b"Running" => Outcome::Running,
            b"Collision" => Outcome::Collision,
            b"ReachGoal" => Outcome::ReachGoal,
            b"Timeout" => Outcome::Timeout,
            _ => return None,
        };
        Some(TransitionBatch {
            setting,
            seed,
            episode,
            chunk,
            last_chunk,
            first_step,
            n_steps,
            n_humans,
            n_actions,
            epsilon,
            human_standing,
            robot_states,
            human_states,
            actions,
            rewards,
            closest_dist_m,
            outcome,
        })
    }
}

/// Decodes a whole message laid out as [`encode_batch`] writes it, with no bytes left over;
/// `None` for anything else (the caller then decodes with serde). Checks structure only: the
/// caller checks the protocol version, kind and body exactly as for a serde-decoded message.
pub(crate) fn decode_batch(bytes: &[u8]) -> Option<Message<TransitionBatch>> {
    let mut r = Reader::new(bytes);
    (r.map_len()? == 2).then_some(())?;
    r.key("header")?;
    let header = r.header()?;
    r.key("body")?;
    let body = r.batch()?;
    (r.pos == bytes.len()).then_some(Message { header, body })
}
