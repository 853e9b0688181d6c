//! The learner's persistence in one place, with no transport attached: the run directory's
//! lock, the checkpoint and the write-ahead log. [`crate::process::run`] uses exactly these
//! functions ([`Store::open`], [`Store::load_checkpoint`], [`replay_plan`],
//! [`commit_checkpoint`]), so a test drives the same code through crashes, power losses and a
//! full disk (`learner/tests/learning/crash.rs`).
//!
//! # Run directory
//!
//! ```text
//! <run_dir>/lock                     flock(2)-style exclusive lock for the life of a learner;
//!                                    holds its pid (text) for the error the next one shows
//! <run_dir>/wal.bin                  write-ahead log of accepted episodes (crate::wal)
//! <run_dir>/checkpoints/latest.ckpt  the last checkpoint (crate::checkpoint)
//! <run_dir>/checkpoints/latest.tmp   a checkpoint being written; removed on open
//! ```
//!
//! # Durability order
//!
//! 1. **Open**: create the directories and sync their parents; take the lock (a second learner
//!    gets [`StoreError::Locked`]); remove a stale `latest.tmp`; open the log — a new one is
//!    created whole and its directory synced, a torn tail is cut off and synced, corruption
//!    refuses the start ([`crate::wal`]).
//! 2. **Accept**: [`Wal::append`] writes and syncs the record; only then is the episode
//!    acknowledged. A failed append leaves no partial record and must not be acknowledged.
//! 3. **Checkpoint** ([`commit_checkpoint`]): write `latest.tmp`, sync it, rename it to
//!    `latest.ckpt`, sync `checkpoints/` — and only then cut the log back to its header. A
//!    failed write (a full disk) removes `latest.tmp`, returns the error and leaves the log
//!    whole, so nothing is lost and a later checkpoint retries.
//!
//! # Recovery
//!
//! The state is the checkpoint (its `accepted_below` per actor: every episode below has been
//! trained on) followed by the log's records in order. A crash after the rename and before the
//! log is cut leaves records the checkpoint already holds: [`replay_plan`] drops every record
//! whose episode is below what the checkpoint (or an earlier record) accepted, so no episode is
//! trained twice. The log is never rewritten on start-up: after recovery it already holds
//! exactly its whole records.

use std::collections::BTreeMap;
use std::fs::{File, OpenOptions};
use std::io::{Read, Write};
use std::path::{Path, PathBuf};

use proto::{Role, TransitionBatch};
use sim::SimConfig;

use crate::checkpoint::{self, CheckpointError, Loaded, RunIdentity, RunInfo};
use crate::core::LearnerCore;
use crate::frame;
use crate::wal::{Wal, WalError};

/// The file-system steps a test can observe or fail, defined beside the durable writes they
/// observe (the learner's `frame` module); the store is where callers reach them.
pub use crate::frame::{Op, Probe};

/// Why the store cannot be opened.
#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    #[error("run directory {dir} is in use by another learner or training (pid {pid})")]
    Locked { dir: PathBuf, pid: String },
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error(transparent)]
    Wal(#[from] WalError),
}

fn io_at(path: &Path) -> impl FnOnce(std::io::Error) -> StoreError + '_ {
    move |source| StoreError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// The exclusive lock on a run directory, held until dropped (the kernel drops it when the
/// process dies, so a crashed learner never leaves a stale lock behind).
#[derive(Debug)]
pub struct RunLock {
    _file: File,
    path: PathBuf,
}

impl RunLock {
    /// Locks `<run_dir>/lock` and writes this process's id into it.
    pub fn acquire(run_dir: &Path) -> Result<Self, StoreError> {
        let path = run_dir.join("lock");
        let mut file = OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(&path)
            .map_err(io_at(&path))?;
        match file.try_lock() {
            Ok(()) => {}
            Err(std::fs::TryLockError::WouldBlock) => {
                let mut pid = String::new();
                let _ = file.read_to_string(&mut pid);
                let pid = match pid.trim() {
                    "" => "unknown".to_string(),
                    p => p.to_string(),
                };
                return Err(StoreError::Locked {
                    dir: run_dir.to_path_buf(),
                    pid,
                });
            }
            Err(std::fs::TryLockError::Error(e)) => return Err(io_at(&path)(e)),
        }
        file.set_len(0)
            .and_then(|()| file.write_all(format!("{}\n", std::process::id()).as_bytes()))
            .map_err(io_at(&path))?;
        Ok(Self { _file: file, path })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }
}

/// `<run_dir>/checkpoints/latest.ckpt`.
pub fn checkpoint_path(run_dir: &Path) -> PathBuf {
    run_dir.join("checkpoints").join("latest.ckpt")
}

/// `<run_dir>/wal.bin`.
pub fn wal_path(run_dir: &Path) -> PathBuf {
    run_dir.join("wal.bin")
}

/// A run directory opened by one learner: its lock, its log and the records the log held.
#[derive(Debug)]
pub struct Store {
    run_dir: PathBuf,
    lock: RunLock,
    wal: Wal,
    records: Vec<Vec<u8>>,
}

impl Store {
    /// Creates (or opens) `run_dir`, locks it and recovers its log (module docs, step 1).
    pub fn open(run_dir: &Path, probe: Probe) -> Result<Self, StoreError> {
        std::fs::create_dir_all(run_dir).map_err(io_at(run_dir))?;
        let lock = RunLock::acquire(run_dir)?;
        let ckpt_dir = run_dir.join("checkpoints");
        std::fs::create_dir_all(&ckpt_dir).map_err(io_at(&ckpt_dir))?;
        // The directories' own entries, so that what is synced inside them can be found.
        for dir in [frame::parent(run_dir), run_dir] {
            frame::sync_dir(dir, &probe).map_err(io_at(dir))?;
        }
        let tmp = checkpoint::tmp_path(&checkpoint_path(run_dir));
        match std::fs::remove_file(&tmp) {
            Ok(()) => {
                tracing::info!(path = %tmp.display(), "removed an unfinished checkpoint");
                probe.after(Op::Removed, &tmp).map_err(io_at(&tmp))?;
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => return Err(io_at(&tmp)(e)),
        }
        let (wal, records) = Wal::open(&wal_path(run_dir), probe)?;
        Ok(Self {
            run_dir: run_dir.to_path_buf(),
            lock,
            wal,
            records,
        })
    }

    pub fn run_dir(&self) -> &Path {
        &self.run_dir
    }

    pub fn checkpoint_path(&self) -> PathBuf {
        checkpoint_path(&self.run_dir)
    }

    /// The log's records when the store was opened, in order.
    pub fn wal_records(&self) -> &[Vec<u8>] {
        &self.records
    }

    /// The checkpoint, if there is one, after checking it is of the run `expected`.
    pub fn load_checkpoint(
        &self,
        expected: &RunIdentity,
    ) -> Result<Option<Loaded>, CheckpointError> {
        let path = self.checkpoint_path();
        let exists = path.try_exists().map_err(|source| CheckpointError::Io {
            path: path.clone(),
            source,
        })?;
        if !exists {
            return Ok(None);
        }
        let loaded = checkpoint::load(&path)?;
        loaded.check_identity(&path, expected)?;
        Ok(Some(loaded))
    }

    /// Appends an accepted episode's record, synced ([`Wal::append`]).
    pub fn append(&mut self, record: &[u8]) -> std::io::Result<()> {
        self.wal.append(record)
    }

    /// Writes a checkpoint and then empties the log ([`commit_checkpoint`]).
    pub fn checkpoint(
        &mut self,
        core: &LearnerCore,
        sim: &SimConfig,
        run: &RunInfo,
    ) -> Result<(), CheckpointError> {
        let path = self.checkpoint_path();
        commit_checkpoint(&path, &mut self.wal, core, sim, run)
    }

    pub fn wal(&self) -> &Wal {
        &self.wal
    }

    /// The lock (keep it alive as long as the run), the log, and its records at opening.
    pub fn into_parts(self) -> (RunLock, Wal, Vec<Vec<u8>>) {
        (self.lock, self.wal, self.records)
    }
}

/// Writes a checkpoint to `path` durably, and only then empties `wal` (module docs, step 3).
/// On error the log still holds every record since the previous checkpoint.
pub fn commit_checkpoint(
    path: &Path,
    wal: &mut Wal,
    core: &LearnerCore,
    sim: &SimConfig,
    run: &RunInfo,
) -> Result<(), CheckpointError> {
    checkpoint::save_with(path, core, sim, run, wal.probe())?;
    wal.truncate().map_err(|source| CheckpointError::Io {
        path: wal.path().to_path_buf(),
        source,
    })
}

/// The log's records sorted for a restart.
#[derive(Debug, Default)]
pub struct ReplayPlan {
    /// Episodes to accept and train on again, in log order.
    pub episodes: Vec<proto::Message<TransitionBatch>>,
    /// Records of episodes the checkpoint (or an earlier record) already holds.
    pub duplicates: u64,
    /// Records that do not decode as an actor's episode.
    pub unreadable: u64,
}

/// Which of the log's `records` are new after a checkpoint that accepted everything below
/// `accepted_below` (per actor): a record of an episode below is a duplicate and is dropped.
pub fn replay_plan(records: &[Vec<u8>], accepted_below: &BTreeMap<u32, u64>) -> ReplayPlan {
    let mut below = accepted_below.clone();
    let mut plan = ReplayPlan::default();
    for rec in records {
        match proto::decode::<TransitionBatch>(rec) {
            Ok(msg) if msg.header.sender.role == Role::Actor => {
                let next = below.entry(msg.header.sender.index).or_insert(0);
                if msg.body.episode < *next {
                    plan.duplicates += 1;
                } else {
                    *next = msg.body.episode + 1;
                    plan.episodes.push(msg);
                }
            }
            _ => plan.unreadable += 1,
        }
    }
    plan
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_second_store_on_the_same_directory_is_refused_with_the_pid() {
        let dir = tempfile::tempdir().unwrap();
        let first = Store::open(dir.path(), Probe::none()).unwrap();
        let err = Store::open(dir.path(), Probe::none()).unwrap_err();
        let msg = err.to_string();
        assert!(matches!(err, StoreError::Locked { .. }), "{msg}");
        assert!(
            msg.contains(&format!("(pid {})", std::process::id()))
                && msg.contains(&dir.path().display().to_string())
                && msg.contains("in use by another learner"),
            "{msg}"
        );
        drop(first);
        Store::open(dir.path(), Probe::none()).unwrap();
    }
}
