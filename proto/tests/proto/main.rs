//! Integration tests of the wire protocol: round trips, typed errors on malformed input, a
//! randomized robustness run and a cross-language (Python `msgpack`) check.

mod direct;
mod malformed;
mod python;
mod roundtrip;
