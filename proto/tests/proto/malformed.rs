//! Every kind of malformed input gives its typed error; a randomized run feeds well over
//! 100 000 inputs without a panic.

use proto::fixtures;
use proto::{
    decode, decode_with_limit, encode, params_crc32, Ack, Body, Control, DecodeError, EncodeError,
    EvalReport, Header, Message, Metrics, SenderId, Status, TransitionBatch, ValidationError,
    Weights, PROTOCOL_VERSION,
};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

/// Encodes without validation (what a buggy or hostile sender could put on the wire).
fn raw<B: Body>(header: &Header, body: &B) -> Vec<u8> {
    rmp_serde::to_vec_named(&Message {
        header: header.clone(),
        body: body.clone(),
    })
    .expect("serialise")
}

fn hdr<B: Body>() -> Header {
    fixtures::header::<B>(SenderId::actor(1), 5, 2)
}

fn valid_batch_bytes() -> Vec<u8> {
    encode(&hdr::<TransitionBatch>(), &fixtures::episode(45, 10, 1)).expect("encode")
}

#[test]
fn every_truncation_is_truncated() {
    let bytes = valid_batch_bytes();
    for n in 0..bytes.len() {
        let err = decode::<TransitionBatch>(&bytes[..n]).expect_err("truncated input decoded");
        assert_eq!(err, DecodeError::Truncated, "prefix of {n} bytes");
    }
    let bytes = encode(&hdr::<Ack>(), &fixtures::ack()).expect("encode");
    for n in 0..bytes.len() {
        assert_eq!(decode::<Ack>(&bytes[..n]), Err(DecodeError::Truncated));
    }
}

#[test]
fn trailing_bytes() {
    let mut bytes = valid_batch_bytes();
    bytes.extend_from_slice(&[0xc0, 0x01]);
    assert_eq!(
        decode::<TransitionBatch>(&bytes),
        Err(DecodeError::TrailingBytes(2))
    );
}

#[test]
fn garbage() {
    for g in [
        &b"hello world"[..],
        &[0xc1][..],
        &[0xff; 64][..],
        &[0x80][..],
        &[0x91, 0xc0][..],
    ] {
        let e = decode::<Metrics>(g).expect_err("garbage decoded");
        assert!(
            matches!(e, DecodeError::Malformed(_) | DecodeError::TrailingBytes(_)),
            "{g:?}: {e:?}"
        );
    }
}

#[test]
fn other_protocol_version() {
    let mut h = hdr::<Metrics>();
    h.protocol_version = PROTOCOL_VERSION + 1;
    let bytes = raw(&h, &fixtures::metrics());
    assert_eq!(
        decode::<Metrics>(&bytes),
        Err(DecodeError::WrongProtocolVersion {
            found: PROTOCOL_VERSION + 1,
            expected: PROTOCOL_VERSION
        })
    );
    // A future version whose body no longer parses as ours is still reported as such.
    #[derive(serde::Serialize)]
    struct Future<'a> {
        header: &'a Header,
        body: &'a str,
    }
    h.protocol_version = 7;
    let bytes = rmp_serde::to_vec_named(&Future {
        header: &h,
        body: "new layout",
    })
    .expect("serialise");
    assert_eq!(
        decode::<Metrics>(&bytes),
        Err(DecodeError::WrongProtocolVersion {
            found: 7,
            expected: PROTOCOL_VERSION
        })
    );
    assert_eq!(proto::probe_protocol_version(&bytes), Some(7));
}

#[test]
fn wrong_kind() {
    // Header says ack, body is a valid control message.
    let h = fixtures::header::<Ack>(SenderId::learner(), 0, 0);
    let bytes = raw(&h, &fixtures::control());
    assert!(matches!(
        decode::<Control>(&bytes),
        Err(DecodeError::WrongKind { .. })
    ));
    // An ack decoded as a control message.
    let bytes = encode(&h, &fixtures::ack()).expect("encode");
    assert!(decode::<Control>(&bytes).is_err());
    // Encoding refuses a header of the wrong kind.
    assert!(matches!(
        encode(&h, &fixtures::control()),
        Err(EncodeError::Invalid(_))
    ));
}

#[test]
fn non_finite_states_rewards_and_weights() {
    for (field, bad) in [
        (0usize, f32::NAN),
        (1, f32::INFINITY),
        (2, f32::NEG_INFINITY),
    ] {
        let mut b = fixtures::episode(45, 10, 1);
        match field {
            0 => b.robot_states[30] = bad,
            1 => b.human_states[700] = bad,
            _ => b.rewards[12] = bad,
        }
        let e = decode::<TransitionBatch>(&raw(&hdr::<TransitionBatch>(), &b))
            .expect_err("non-finite decoded");
        assert!(
            matches!(e, DecodeError::Invalid(ValidationError::NonFinite { .. })),
            "{e:?}"
        );
        assert!(matches!(
            encode(&hdr::<TransitionBatch>(), &b),
            Err(EncodeError::Invalid(ValidationError::NonFinite { .. }))
        ));
    }
    let mut b = fixtures::episode(45, 10, 1);
    b.closest_dist_m[3] = f32::NAN;
    assert!(matches!(
        decode::<TransitionBatch>(&raw(&hdr::<TransitionBatch>(), &b)),
        Err(DecodeError::Invalid(ValidationError::NonFinite {
            field: "closest_dist_m",
            index: 3
        }))
    ));
    // With the checksum matching the NaN, finiteness still catches it.
    let mut w = fixtures::sarl_weights(3);
    w.params[1000] = f32::NAN;
    w.crc32 = params_crc32(&w.params);
    assert_eq!(
        decode::<Weights>(&raw(&hdr::<Weights>(), &w)),
        Err(DecodeError::Invalid(ValidationError::NonFinite {
            field: "params",
            index: 1000
        }))
    );
    let mut m = fixtures::metrics();
    m.values.insert("loss".into(), f64::NAN);
    assert!(decode::<Metrics>(&raw(&hdr::<Metrics>(), &m)).is_err());
    let mut r = fixtures::eval_report();
    r.settings[2].mean_return = f64::INFINITY;
    assert!(matches!(
        decode::<EvalReport>(&raw(&hdr::<EvalReport>(), &r)),
        Err(DecodeError::Invalid(ValidationError::NonFinite { .. }))
    ));
    let mut s = fixtures::status();
    s.uptime_s = f64::NAN;
    assert!(decode::<Status>(&raw(&hdr::<Status>(), &s)).is_err());
}

#[test]
fn wrong_lengths_and_limits() {
    let h = hdr::<TransitionBatch>();
    let mut b = fixtures::episode(45, 10, 1);
    b.robot_states.pop();
    assert!(matches!(
        decode::<TransitionBatch>(&raw(&h, &b)),
        Err(DecodeError::Invalid(ValidationError::LengthMismatch {
            field: "robot_states",
            ..
        }))
    ));
    let mut b = fixtures::episode(45, 10, 1);
    b.n_humans = 9;
    assert!(matches!(
        decode::<TransitionBatch>(&raw(&h, &b)),
        Err(DecodeError::Invalid(ValidationError::LengthMismatch { .. }))
    ));
    let mut b = fixtures::episode(45, 10, 1);
    b.n_humans = 100_000;
    assert!(matches!(
        decode::<TransitionBatch>(&raw(&h, &b)),
        Err(DecodeError::Invalid(ValidationError::LimitExceeded {
            field: "n_humans",
            ..
        }))
    ));
    let mut b = fixtures::episode(45, 10, 1);
    b.actions[4] = 51;
    assert!(matches!(
        decode::<TransitionBatch>(&raw(&h, &b)),
        Err(DecodeError::Invalid(ValidationError::InvalidField {
            field: "actions",
            ..
        }))
    ));
    let mut b = fixtures::episode(45, 10, 1);
    b.last_chunk = false;
    assert!(decode::<TransitionBatch>(&raw(&h, &b)).is_err());

    let hw = hdr::<Weights>();
    let mut w = fixtures::sarl_weights(1);
    w.params.pop();
    w.crc32 = params_crc32(&w.params);
    assert!(matches!(
        decode::<Weights>(&raw(&hw, &w)),
        Err(DecodeError::Invalid(ValidationError::LengthMismatch {
            field: "params",
            ..
        }))
    ));
    let mut w = fixtures::sarl_weights(1);
    w.params[5] += 1.0;
    assert!(matches!(
        decode::<Weights>(&raw(&hw, &w)),
        Err(DecodeError::Invalid(
            ValidationError::ChecksumMismatch { .. }
        ))
    ));
    let mut w = fixtures::sarl_weights(1);
    w.network.tensors[0].shape = vec![u32::MAX, u32::MAX, u32::MAX];
    assert!(matches!(
        decode::<Weights>(&raw(&hw, &w)),
        Err(DecodeError::Invalid(ValidationError::LimitExceeded { .. }))
    ));
}

#[test]
fn oversized() {
    let bytes = valid_batch_bytes();
    assert_eq!(
        decode_with_limit::<TransitionBatch>(&bytes, 1000),
        Err(DecodeError::Oversized {
            len: bytes.len(),
            limit: 1000
        })
    );
    let huge = vec![0u8; proto::DEFAULT_MAX_MESSAGE_BYTES + 1];
    assert!(matches!(
        decode::<Weights>(&huge),
        Err(DecodeError::Oversized { .. })
    ));
    // A length prefix claiming 4 GiB in a short input.
    let lie = [
        0x81, 0xa6, b'h', b'e', b'a', b'd', b'e', b'r', 0xc6, 0xff, 0xff, 0xff, 0xff,
    ];
    assert!(decode::<Weights>(&lie).is_err());
}

#[test]
fn invalid_header_fields() {
    // A run id with a wildcard cannot be smuggled in.
    let bytes = encode(&hdr::<Ack>(), &fixtures::ack()).expect("encode");
    let needle = b"fixture";
    let pos = bytes
        .windows(needle.len())
        .position(|w| w == needle)
        .expect("run id in bytes");
    let mut bad = bytes.clone();
    bad[pos] = b'*';
    assert!(matches!(
        decode::<Ack>(&bad),
        Err(DecodeError::Malformed(_))
    ));
}

/// Decodes `input` as every message type; any outcome but a panic is fine, and an `Ok` must be
/// a valid message (validated again here).
fn decode_all(input: &[u8], counts: &mut [u64; 2]) {
    fn one<B: Body>(input: &[u8], counts: &mut [u64; 2]) {
        match decode::<B>(input) {
            Ok(m) => {
                assert!(m.body.validate().is_ok());
                counts[0] += 1;
            }
            Err(_) => counts[1] += 1,
        }
    }
    one::<TransitionBatch>(input, counts);
    one::<Weights>(input, counts);
    one::<EvalReport>(input, counts);
    one::<Metrics>(input, counts);
    one::<Status>(input, counts);
    one::<Ack>(input, counts);
    one::<Control>(input, counts);
}

#[test]
fn randomized_malformed_inputs_never_panic() {
    let mut rng = StdRng::seed_from_u64(0x005e_edf5_u64);
    let samples: Vec<Vec<u8>> = vec![
        encode(&hdr::<TransitionBatch>(), &fixtures::episode(8, 3, 1)).expect("encode"),
        encode(&hdr::<TransitionBatch>(), &fixtures::episode(45, 10, 2)).expect("encode"),
        encode(&hdr::<Weights>(), &small_weights()).expect("encode"),
        encode(&hdr::<EvalReport>(), &fixtures::eval_report()).expect("encode"),
        encode(&hdr::<Metrics>(), &fixtures::metrics()).expect("encode"),
        encode(&hdr::<Status>(), &fixtures::status()).expect("encode"),
        encode(&hdr::<Ack>(), &fixtures::ack()).expect("encode"),
        encode(&hdr::<Control>(), &fixtures::control()).expect("encode"),
    ];
    let mut counts = [0u64; 2];
    let mut inputs = 0u64;
    let mut buf = Vec::new();
    while inputs < 120_000 {
        let base = &samples[rng.gen_range(0..samples.len())];
        buf.clear();
        match rng.gen_range(0..5) {
            // Random bytes, sometimes starting with a map marker to get past the first byte.
            0 => {
                let n = rng.gen_range(0..256);
                buf.extend((0..n).map(|_| rng.gen::<u8>()));
                if rng.gen_bool(0.5) && !buf.is_empty() {
                    buf[0] = 0x82;
                }
            }
            // Truncation.
            1 => buf.extend_from_slice(&base[..rng.gen_range(0..base.len())]),
            // Bit flips.
            2 => {
                buf.extend_from_slice(base);
                for _ in 0..rng.gen_range(1..=8) {
                    let i = rng.gen_range(0..buf.len());
                    buf[i] ^= 1 << rng.gen_range(0..8);
                }
            }
            // Random byte overwrites in the first 64 bytes (markers, lengths, header).
            3 => {
                buf.extend_from_slice(base);
                for _ in 0..rng.gen_range(1..=4) {
                    let i = rng.gen_range(0..buf.len().min(64));
                    buf[i] = rng.gen();
                }
            }
            // Splices of two messages.
            _ => {
                let other = &samples[rng.gen_range(0..samples.len())];
                let a = rng.gen_range(0..base.len());
                let b = rng.gen_range(0..other.len());
                buf.extend_from_slice(&base[..a]);
                buf.extend_from_slice(&other[b..]);
            }
        }
        decode_all(&buf, &mut counts);
        inputs += 1;
    }
    assert!(inputs >= 100_000);
    // Nearly everything must be rejected (a flipped mantissa bit can stay valid).
    assert!(counts[1] > counts[0] * 50, "{counts:?}");
}

fn small_weights() -> Weights {
    let network = proto::NetworkDesc {
        kind: proto::NetworkKind::LstmRl,
        tensors: vec![
            proto::TensorDesc::new("l.weight", [4, 3]),
            proto::TensorDesc::new("l.bias", [4]),
        ],
    };
    Weights::new(2, network, (0..16).map(|i| i as f32 * 0.5).collect()).expect("valid")
}
