//! The hand-written codec of `TransitionBatch` (`proto::direct`) against serde, the reference:
//! the encoder writes serde's bytes exactly, the decoder takes the fast path on what the encoder
//! writes, and on every input, valid or corrupted, `decode` returns exactly what serde alone
//! (`codec::decode_with_limit_serde`) returns.

use proto::codec::decode_with_limit_serde;
use proto::{
    decode, encode, Body, DecodeError, Header, Message, Outcome, Role, RunId, SenderId,
    TransitionBatch, DEFAULT_MAX_MESSAGE_BYTES,
};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use serde::Serialize;

/// A value spread over every MessagePack uint width (fixint, u8, u16, u32, u64).
fn any_u64(rng: &mut StdRng) -> u64 {
    match rng.gen_range(0..6) {
        0 => rng.gen_range(0..0x80),
        1 => rng.gen_range(0x80..=0xff),
        2 => rng.gen_range(0x100..=0xffff),
        3 => rng.gen_range(0x1_0000..=0xffff_ffff),
        4 => rng.gen_range(0x1_0000_0000..=u64::MAX),
        _ => [0, 0x7f, 0x80, 0xff, 0x100, 0xffff, 0x1_0000, u64::MAX][rng.gen_range(0..8)],
    }
}

fn any_f32(rng: &mut StdRng) -> f32 {
    match rng.gen_range(0..8) {
        0 => -0.0,
        1 => f32::MIN_POSITIVE / 3.0, // subnormal
        2 => f32::MAX,
        3 => rng.gen_range(-1e6..1e6),
        _ => rng.gen_range(-10.0..10.0),
    }
}

fn name(rng: &mut StdRng, max_len: usize) -> String {
    const CHARS: &[u8] = b"abcdefghijklmnopqrstuvwxyz0123456789_-";
    let len = rng.gen_range(1..=max_len);
    (0..len)
        .map(|_| CHARS[rng.gen_range(0..CHARS.len())] as char)
        .collect()
}

fn random_header(rng: &mut StdRng) -> Header {
    let role = Role::ALL[rng.gen_range(0..Role::ALL.len())];
    let sender = SenderId::new(role, any_u64(rng) as u32);
    let run = RunId::new(name(rng, 60)).expect("run id");
    Header::new::<TransitionBatch>(run, sender, any_u64(rng), any_u64(rng))
}

/// A valid batch with random dimensions and contents (`max_steps` bounds its length).
fn random_batch(rng: &mut StdRng, max_steps: u32) -> TransitionBatch {
    let t = rng.gen_range(1..=max_steps);
    let h = if max_steps <= 60 && rng.gen_bool(0.1) {
        rng.gen_range(0..=256)
    } else {
        rng.gen_range(0..=12)
    };
    let n_actions = if rng.gen_bool(0.5) {
        51
    } else {
        rng.gen_range(1..=4096)
    };
    let (tu, hu) = (t as usize, h as usize);
    let col = |rng: &mut StdRng, n: usize| (0..n).map(|_| any_f32(rng)).collect::<Vec<_>>();
    let outcome = [
        Outcome::Running,
        Outcome::Collision,
        Outcome::ReachGoal,
        Outcome::Timeout,
    ][rng.gen_range(0..4)];
    let closest_dist_m = (0..tu)
        .map(|_| {
            if h == 0 && rng.gen_bool(0.5) {
                f32::INFINITY
            } else {
                any_f32(rng)
            }
        })
        .collect();
    let b = TransitionBatch {
        setting: name(rng, 64),
        seed: any_u64(rng),
        episode: any_u64(rng),
        chunk: any_u64(rng) as u32,
        last_chunk: outcome != Outcome::Running,
        first_step: rng.gen_range(0..=u32::MAX - t),
        n_steps: t,
        n_humans: h,
        n_actions,
        epsilon: if rng.gen_bool(0.2) {
            [0.0, 1.0][rng.gen_range(0..2)]
        } else {
            rng.gen_range(0.0..=1.0)
        },
        human_standing: (0..hu).map(|_| rng.gen_bool(0.5)).collect(),
        robot_states: col(rng, (tu + 1) * 9),
        human_states: col(rng, (tu + 1) * hu * 5),
        actions: (0..tu).map(|_| rng.gen_range(0..n_actions)).collect(),
        rewards: col(rng, tu * 5),
        closest_dist_m,
        outcome,
    };
    b.validate().expect("generator makes valid batches");
    b
}

/// The `i`-th message of a run: every 200th a long batch (up to 10,000 steps), which reaches
/// the 16- and 32-bit length markers of `bin` and the 16-bit one of arrays.
fn random_message(rng: &mut StdRng, i: u32) -> (Header, TransitionBatch) {
    let max_steps = if i.is_multiple_of(200) { 10_000 } else { 60 };
    (random_header(rng), random_batch(rng, max_steps))
}

/// serde's encoding, the reference (named fields, as `codec` configures rmp-serde).
fn serde_bytes(header: &Header, body: &TransitionBatch) -> Vec<u8> {
    rmp_serde::to_vec_named(&Message {
        header: header.clone(),
        body: body.clone(),
    })
    .expect("serialise")
}

fn same_as_serde(bytes: &[u8]) -> Result<Message<TransitionBatch>, DecodeError> {
    let fast = decode::<TransitionBatch>(bytes);
    let reference = decode_with_limit_serde::<TransitionBatch>(bytes, DEFAULT_MAX_MESSAGE_BYTES);
    assert_eq!(fast, reference, "decode differs from serde on {bytes:02x?}");
    fast
}

#[test]
fn encoder_writes_serdes_bytes() {
    let mut rng = StdRng::seed_from_u64(11);
    for i in 0..2_000 {
        let (h, b) = random_message(&mut rng, i);
        assert_eq!(
            encode(&h, &b).expect("encode"),
            serde_bytes(&h, &b),
            "batch {i}"
        );
    }
}

#[test]
fn decoder_takes_the_fast_path_and_agrees_with_serde() {
    let mut rng = StdRng::seed_from_u64(12);
    for i in 0..2_000 {
        let (h, b) = random_message(&mut rng, i);
        let bytes = encode(&h, &b).expect("encode");
        let direct = TransitionBatch::decode_direct(&bytes).expect("fast path taken");
        assert_eq!((&direct.header, &direct.body), (&h, &b), "batch {i}");
        let m = same_as_serde(&bytes).expect("decodes");
        assert_eq!((m.header, m.body), (h, b));
    }
}

/// The same fields in another order (as another language's encoder may write them).
#[derive(Serialize)]
struct Reordered<'a> {
    body: &'a TransitionBatch,
    header: &'a Header,
}

#[test]
fn another_field_order_falls_back_to_serde() {
    let mut rng = StdRng::seed_from_u64(13);
    let (h, b) = (random_header(&mut rng), random_batch(&mut rng, 45));
    let bytes = rmp_serde::to_vec_named(&Reordered {
        body: &b,
        header: &h,
    })
    .expect("serialise");
    assert!(TransitionBatch::decode_direct(&bytes).is_none());
    let m = same_as_serde(&bytes).expect("serde decodes any field order");
    assert_eq!((m.header, m.body), (h, b));
}

#[test]
fn corrupted_inputs_decode_exactly_as_with_serde() {
    let mut rng = StdRng::seed_from_u64(14);
    let (mut ok, mut err) = (0u32, 0u32);
    let mut kinds = std::collections::HashSet::new();
    for i in 0..120_000u32 {
        // Mostly small messages, whose structure is a larger share of their bytes.
        let max_steps = if i % 3 == 0 { 45 } else { 3 };
        let (h, b) = (random_header(&mut rng), random_batch(&mut rng, max_steps));
        let mut bytes = encode(&h, &b).expect("encode");
        // Corrupt mostly the structure (the first few hundred bytes), sometimes anywhere.
        let span = if rng.gen_bool(0.7) {
            bytes.len().min(400)
        } else {
            bytes.len()
        };
        match rng.gen_range(0..6) {
            0 | 1 => {
                for _ in 0..rng.gen_range(1..=3) {
                    let p = rng.gen_range(0..span);
                    bytes[p] = rng.gen();
                }
            }
            2 => {
                let p = rng.gen_range(0..span);
                bytes[p] ^= 1 << rng.gen_range(0..8);
            }
            3 => bytes.truncate(rng.gen_range(0..bytes.len())),
            4 => {
                let p = rng.gen_range(0..=span);
                bytes.insert(p, rng.gen());
            }
            _ => {
                let p = rng.gen_range(0..span);
                bytes.remove(p);
            }
        }
        match same_as_serde(&bytes) {
            Ok(_) => ok += 1,
            Err(e) => {
                err += 1;
                kinds.insert(std::mem::discriminant(&e));
            }
        }
    }
    // The corpus reaches both outcomes and several kinds of error.
    assert!(ok > 1_000 && err > 10_000, "ok {ok}, err {err}");
    assert!(kinds.len() >= 4, "only {} kinds of error", kinds.len());
}

#[test]
fn prepared_messages_write_the_encoded_bytes_in_place() {
    use std::mem::MaybeUninit;
    let mut rng = StdRng::seed_from_u64(15);
    for i in 0..500 {
        let (h, b) = (random_header(&mut rng), random_batch(&mut rng, 60));
        let bytes = encode(&h, &b).expect("encode");
        let p = proto::prepare(&h, &b, DEFAULT_MAX_MESSAGE_BYTES)
            .expect("valid")
            .expect("batches have a hand-written codec");
        assert_eq!(p.encoded_len(), bytes.len(), "batch {i}");
        let mut out = vec![MaybeUninit::<u8>::uninit(); p.encoded_len()];
        assert_eq!(p.write(&mut out).expect("write"), &bytes[..], "batch {i}");
        // A destination of another size is refused, not overrun or left part-written.
        for len in [0, bytes.len() - 1, bytes.len() + 1] {
            let mut out = vec![MaybeUninit::<u8>::uninit(); len];
            assert!(p.write(&mut out).is_err(), "destination of {len} bytes");
        }
    }
}

#[test]
fn prepare_validates_like_encode() {
    let mut rng = StdRng::seed_from_u64(16);
    let (h, mut b) = (random_header(&mut rng), random_batch(&mut rng, 10));
    let len = encode(&h, &b).expect("encode").len();
    assert_eq!(
        proto::prepare(&h, &b, len - 1).map(|p| p.map(|p| p.encoded_len())),
        Err(proto::EncodeError::Oversized {
            len,
            limit: len - 1
        })
    );
    b.rewards[3] = f32::NAN;
    assert_eq!(
        proto::prepare(&h, &b, DEFAULT_MAX_MESSAGE_BYTES).map(|p| p.is_some()),
        encode(&h, &b).map(|_| true)
    );
    assert!(proto::prepare(&h, &b, DEFAULT_MAX_MESSAGE_BYTES).is_err());
    // Messages without a hand-written codec are encoded with `encode_into`.
    let m = proto::fixtures::metrics();
    let hm = proto::fixtures::header::<proto::Metrics>(SenderId::learner(), 0, 0);
    assert!(matches!(
        proto::prepare(&hm, &m, DEFAULT_MAX_MESSAGE_BYTES),
        Ok(None)
    ));
}
