//! The transport test suite, written once and run against both backends (`zenoh` and
//! `iceoryx2` data planes). Loopback only, multicast off, ephemeral ports, unique run ids and
//! iceoryx2 prefixes per test, every wait bounded by a timeout.

mod alive_bound;
mod harness;
mod stall;
mod suite;
