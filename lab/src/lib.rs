//! `lab`: the analysis of fsrl runs, as a library a notebook or another tool can call: evaluation
//! reports with their intervals and the paper's numbers ([`report`]), comparisons across runs and
//! arms ([`compare`]), scoring policies for those reports ([`evaluation`]), which weights of a run are its policy ([`select`], [`revalidation`], [`policy_file`]), the
//! validation frontier ([`frontier`]), the figures' numbers ([`figures`], [`picture`]) and the
//! paper's grid of runs: planning, state on disk, shards and the time it will take ([`grid`]),
//! and the ORCA robot's baseline tables ([`baseline`]).
//!
//! It reads run directories and model files and writes text; it opens no socket and starts no
//! process (the `fsrl` binary does, and calls in here for everything else). Errors are messages
//! for a person (`anyhow` with the file they concern).

pub mod baseline;
pub mod compare;
pub mod evaluation;
pub mod figures;
pub mod frontier;
pub mod grid;
pub mod picture;
pub mod policy_choice;
pub mod policy_file;
pub mod report;
pub mod revalidation;
pub mod robustness;
pub mod run;
pub mod select;
