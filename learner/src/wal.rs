//! A write-ahead log of accepted episodes: each is appended and synced before the learner
//! acknowledges it, so an acknowledged episode survives a crash between checkpoints. A
//! checkpoint (made durable first: the `store` module above this one) truncates the log.
//!
//! # On-disk format (`wal.bin`, format version 1)
//!
//! ```text
//! header:  magic b"FSRLWAL\0" (8 bytes) | format version (u32 LE)
//! record:  length n (u32 LE) | CRC-32 of the body (u32 LE)
//!          | CRC-32 of the previous 8 bytes (u32 LE) | body (n bytes)
//! ```
//!
//! The record head carries its own checksum, so a damaged length is told apart from a record
//! cut short by a crash. A body is one encoded `proto::Message<TransitionBatch>`.
//!
//! # Durability
//!
//! - A new (or empty) log is created whole, header included, through a temporary file that is
//!   synced, renamed and whose directory is synced (`frame::replace`): a log either
//!   does not exist or has a whole header.
//! - [`Wal::append`] writes the record and `fdatasync`s it; only then may the episode be
//!   acknowledged. If writing or syncing fails (a full disk: `ENOSPC` mid-record), the file is
//!   cut back to its length before the append and synced, so no partial record stays behind;
//!   if even that fails, the next append retries it first.
//! - [`Wal::truncate`] cuts the log back to its header; it is called only after a checkpoint
//!   holding every record is durable.
//!
//! # Recovery ([`Wal::open`])
//!
//! Only the last record can be unsynced when the process dies, so only damage at the tail is
//! a crash: fewer bytes left than a record head, a record whose length runs past the end of the
//! file, a last record whose body checksum fails and which ends exactly at the end of the file,
//! or a head that fails its checksum followed only by zero bytes (a file extended but never
//! written). The log is then cut to the end of the last whole record and synced — no rewrite.
//! Anything else (a bad record followed by more bytes, a missing or garbled header, an unknown
//! format version) is an error naming the file and the offset: the learner refuses to start
//! rather than skip acknowledged episodes or append behind garbage.

use std::fs::{File, OpenOptions};
use std::io::Write;
use std::path::{Path, PathBuf};

use crate::frame::{self, Op, Probe};

/// The first bytes of every log.
pub const MAGIC: &[u8; 8] = b"FSRLWAL\0";
/// Bumped whenever the layout changes incompatibly.
pub const FORMAT_VERSION: u32 = 1;
/// Length of the file header (magic and version).
pub const HEADER_LEN: u64 = 12;
/// Length of a record head (length, body CRC, head CRC).
const HEAD_LEN: usize = 12;

/// Why a log cannot be opened.
#[derive(Debug, thiserror::Error)]
pub enum WalError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error(
        "{0}: not an fsrl write-ahead log (missing or garbled header; a log of an older fsrl \
         has none); refusing to start — move it away to discard the episodes it holds"
    )]
    NotALog(PathBuf),
    #[error("{path}: write-ahead log format version {found}, this build reads version {expected}")]
    Version {
        path: PathBuf,
        found: u32,
        expected: u32,
    },
    #[error(
        "{path}: corrupt write-ahead log record at byte {offset} ({reason}) with {following} \
         more bytes after it; refusing to start rather than drop the episodes behind it"
    )]
    Corrupt {
        path: PathBuf,
        offset: u64,
        reason: &'static str,
        following: u64,
    },
}

/// What [`scan`] found after the header.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct Scan {
    /// Every whole record's body, in order.
    pub records: Vec<Vec<u8>>,
    /// End of the last whole record (the file's length after recovery).
    pub valid_end: u64,
    /// Damage at the tail (a crash mid-append), or corruption inside the log.
    pub damage: Option<Damage>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Damage {
    Tail(&'static str),
    Corrupt {
        offset: u64,
        reason: &'static str,
        following: u64,
    },
}

fn u32_at(bytes: &[u8], at: usize) -> u32 {
    let mut b = [0u8; 4];
    b.copy_from_slice(&bytes[at..at + 4]);
    u32::from_le_bytes(b)
}

/// Reads the records of a whole log file (header included) and classifies any damage.
pub(crate) fn scan(bytes: &[u8]) -> Scan {
    let n = bytes.len();
    let mut at = HEADER_LEN as usize;
    let mut records = Vec::new();
    let damage = loop {
        let rest = n - at;
        if rest == 0 {
            break None;
        }
        if rest < HEAD_LEN {
            break Some(Damage::Tail("a record head cut short"));
        }
        let len = u32_at(bytes, at) as usize;
        let body_crc = u32_at(bytes, at + 4);
        if crc32fast::hash(&bytes[at..at + 8]) != u32_at(bytes, at + 8) {
            if bytes[at..].iter().all(|&b| b == 0) {
                break Some(Damage::Tail("zero bytes after the last record"));
            }
            break Some(Damage::Corrupt {
                offset: at as u64,
                reason: "record head checksum mismatch",
                following: (rest - HEAD_LEN) as u64,
            });
        }
        let end = at + HEAD_LEN + len;
        if end > n {
            break Some(Damage::Tail(
                "the last record runs past the end of the file",
            ));
        }
        let body = &bytes[at + HEAD_LEN..end];
        if crc32fast::hash(body) != body_crc {
            if end == n {
                break Some(Damage::Tail("the last record's checksum fails"));
            }
            break Some(Damage::Corrupt {
                offset: at as u64,
                reason: "record checksum mismatch",
                following: (n - end) as u64,
            });
        }
        records.push(body.to_vec());
        at = end;
    };
    Scan {
        records,
        valid_end: at as u64,
        damage,
    }
}

/// One record as it is appended.
pub(crate) fn encode_record(body: &[u8]) -> std::io::Result<Vec<u8>> {
    let len = u32::try_from(body.len()).map_err(|_| {
        std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            format!("a record of {} bytes does not fit the log", body.len()),
        )
    })?;
    let mut rec = Vec::with_capacity(body.len() + HEAD_LEN);
    rec.extend_from_slice(&len.to_le_bytes());
    rec.extend_from_slice(&crc32fast::hash(body).to_le_bytes());
    let head_crc = crc32fast::hash(&rec);
    rec.extend_from_slice(&head_crc.to_le_bytes());
    rec.extend_from_slice(body);
    Ok(rec)
}

fn file_header() -> [u8; HEADER_LEN as usize] {
    let mut h = [0u8; HEADER_LEN as usize];
    h[..8].copy_from_slice(MAGIC);
    h[8..].copy_from_slice(&FORMAT_VERSION.to_le_bytes());
    h
}

/// An open log.
#[derive(Debug)]
pub struct Wal {
    path: PathBuf,
    file: File,
    /// Length of the header and the whole records: where the next record starts.
    len: u64,
    /// The file may be longer than `len` (a failed append whose roll-back failed too).
    dirty: bool,
    probe: Probe,
}

impl Wal {
    /// Opens (or creates) the log at `path` and returns it with every record it holds;
    /// recovers from a crash mid-append and refuses anything else (module docs).
    pub fn open(path: &Path, probe: Probe) -> Result<(Self, Vec<Vec<u8>>), WalError> {
        let io = |source| WalError::Io {
            path: path.to_path_buf(),
            source,
        };
        let bytes = match std::fs::read(path) {
            Ok(b) => b,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Vec::new(),
            Err(e) => return Err(io(e)),
        };
        let mut records = Vec::new();
        let mut len = HEADER_LEN;
        let mut cut = None;
        if bytes.is_empty() {
            frame::replace_observed(path, &path.with_extension("tmp"), &[&file_header()], &probe)
                .map_err(|(path, source)| WalError::Io { path, source })?;
        } else {
            if bytes.len() < HEADER_LEN as usize || &bytes[..8] != MAGIC {
                return Err(WalError::NotALog(path.to_path_buf()));
            }
            let found = u32_at(&bytes, 8);
            if found != FORMAT_VERSION {
                return Err(WalError::Version {
                    path: path.to_path_buf(),
                    found,
                    expected: FORMAT_VERSION,
                });
            }
            let s = scan(&bytes);
            match s.damage {
                None => {}
                Some(Damage::Tail(why)) => cut = Some(why),
                Some(Damage::Corrupt {
                    offset,
                    reason,
                    following,
                }) => {
                    return Err(WalError::Corrupt {
                        path: path.to_path_buf(),
                        offset,
                        reason,
                        following,
                    })
                }
            }
            records = s.records;
            len = s.valid_end;
        }
        let file = OpenOptions::new().append(true).open(path).map_err(io)?;
        if let Some(why) = cut {
            tracing::warn!(
                path = %path.display(),
                dropped_bytes = bytes.len() as u64 - len,
                "write-ahead log: {why} (a crash mid-append); cutting the log after its last whole record"
            );
            file.set_len(len).map_err(io)?;
            probe.after(Op::SetLen, path).map_err(io)?;
            file.sync_all().map_err(io)?;
            probe.after(Op::Synced, path).map_err(io)?;
        }
        Ok((
            Self {
                path: path.to_path_buf(),
                file,
                len,
                dirty: false,
                probe,
            },
            records,
        ))
    }

    /// Appends one record and syncs it to disk. On error the log is as it was before (no
    /// partial record stays behind) and the record must not be acknowledged.
    pub fn append(&mut self, bytes: &[u8]) -> std::io::Result<()> {
        if self.dirty {
            self.cut_back()?;
        }
        let rec = encode_record(bytes)?;
        self.dirty = true;
        match self.write_synced(&rec) {
            Ok(()) => {
                self.len += rec.len() as u64;
                self.dirty = false;
                Ok(())
            }
            Err(e) => {
                if let Err(again) = self.cut_back() {
                    tracing::warn!(
                        path = %self.path.display(),
                        "write-ahead log: cannot remove a failed append ({again}); retrying before the next one"
                    );
                }
                Err(e)
            }
        }
    }

    fn write_synced(&mut self, rec: &[u8]) -> std::io::Result<()> {
        self.file.write_all(rec)?;
        self.probe.after(Op::Written, &self.path)?;
        self.file.sync_data()?;
        self.probe.after(Op::Synced, &self.path)
    }

    /// Cuts the file back to its whole records and syncs that.
    fn cut_back(&mut self) -> std::io::Result<()> {
        self.file.set_len(self.len)?;
        self.probe.after(Op::SetLen, &self.path)?;
        self.file.sync_data()?;
        self.dirty = false;
        self.probe.after(Op::Synced, &self.path)
    }

    /// Empties the log, keeping its header (after a durable checkpoint holds every record).
    pub fn truncate(&mut self) -> std::io::Result<()> {
        self.file.set_len(HEADER_LEN)?;
        self.len = HEADER_LEN;
        self.dirty = false;
        self.probe.after(Op::SetLen, &self.path)?;
        self.file.sync_all()?;
        self.probe.after(Op::Synced, &self.path)
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// What the log reports its steps to.
    pub fn probe(&self) -> &Probe {
        &self.probe
    }

    /// Length of the header and the whole records, in bytes.
    pub fn len_bytes(&self) -> u64 {
        self.len
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn open(p: &Path) -> Result<(Wal, Vec<Vec<u8>>), WalError> {
        Wal::open(p, Probe::none())
    }

    fn strs(records: &[Vec<u8>]) -> Vec<&str> {
        records
            .iter()
            .map(|r| std::str::from_utf8(r).unwrap())
            .collect()
    }

    #[test]
    fn records_survive_a_reopen_and_truncate_keeps_the_header() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("wal.bin");
        let (mut w, recs) = open(&p).unwrap();
        assert!(recs.is_empty());
        assert_eq!(std::fs::read(&p).unwrap(), file_header());
        w.append(b"one").unwrap();
        w.append(b"two!").unwrap();
        drop(w);
        let (mut w, recs) = open(&p).unwrap();
        assert_eq!(strs(&recs), ["one", "two!"]);
        w.append(b"three").unwrap();
        assert_eq!(strs(&open(&p).unwrap().1), ["one", "two!", "three"]);
        w.truncate().unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), file_header());
        w.append(b"four").unwrap();
        assert_eq!(strs(&open(&p).unwrap().1), ["four"]);
        assert!(!dir.path().join("wal.tmp").exists());
        // An empty file (a log truncated by an older fsrl) gets a header.
        std::fs::write(&p, b"").unwrap();
        assert!(open(&p).unwrap().1.is_empty());
        assert_eq!(std::fs::read(&p).unwrap(), file_header());
    }

    /// Every cut inside the last record is a torn tail: the log is cut back to the whole
    /// records, synced, and appending goes on after them.
    #[test]
    fn a_torn_tail_is_cut_off_at_every_length() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("wal.bin");
        let (mut w, _) = open(&p).unwrap();
        w.append(b"one").unwrap();
        let whole = w.len_bytes();
        w.append(b"second record").unwrap();
        drop(w);
        let full = std::fs::read(&p).unwrap();
        for cut in whole as usize..full.len() {
            std::fs::write(&p, &full[..cut]).unwrap();
            let (mut w, recs) = open(&p).unwrap();
            assert_eq!(strs(&recs), ["one"], "cut at {cut}");
            assert_eq!(std::fs::metadata(&p).unwrap().len(), whole, "cut at {cut}");
            w.append(b"next").unwrap();
            assert_eq!(strs(&open(&p).unwrap().1), ["one", "next"], "cut at {cut}");
        }
        // The last record's body damaged, ending exactly at the end of the file.
        let mut bad = full.clone();
        *bad.last_mut().unwrap() ^= 1;
        std::fs::write(&p, &bad).unwrap();
        assert_eq!(strs(&open(&p).unwrap().1), ["one"]);
        // A file extended with zeros that were never written.
        let mut zeros = full[..whole as usize].to_vec();
        zeros.extend_from_slice(&[0; 40]);
        std::fs::write(&p, &zeros).unwrap();
        assert_eq!(strs(&open(&p).unwrap().1), ["one"]);
        assert_eq!(std::fs::metadata(&p).unwrap().len(), whole);
    }

    /// Damage followed by more records is not a crash: opening fails, names file and offset,
    /// and leaves the file untouched.
    #[test]
    fn corruption_before_the_tail_is_refused_with_file_and_offset() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("wal.bin");
        let (mut w, _) = open(&p).unwrap();
        for r in ["one", "two", "three"] {
            w.append(r.as_bytes()).unwrap();
        }
        drop(w);
        let good = std::fs::read(&p).unwrap();
        let second = HEADER_LEN as usize + HEAD_LEN + 3;
        // Any single byte of the first two records (head or body) flipped.
        for i in HEADER_LEN as usize..second + HEAD_LEN + 3 {
            let mut bad = good.clone();
            bad[i] ^= 0x10;
            std::fs::write(&p, &bad).unwrap();
            let err = open(&p)
                .err()
                .unwrap_or_else(|| panic!("byte {i} accepted"));
            let offset = if i < second {
                HEADER_LEN as usize
            } else {
                second
            };
            assert!(
                matches!(err, WalError::Corrupt { offset: o, .. } if o == offset as u64),
                "byte {i}: {err}"
            );
            let msg = err.to_string();
            assert!(
                msg.contains("wal.bin") && msg.contains(&format!("byte {offset}")),
                "{msg}"
            );
            assert_eq!(std::fs::read(&p).unwrap(), bad, "byte {i}: file changed");
        }
        // A length that runs past the end of the file, in the middle: not a torn tail.
        let mut long = good.clone();
        long[HEADER_LEN as usize..HEADER_LEN as usize + 4].copy_from_slice(&1000u32.to_le_bytes());
        std::fs::write(&p, &long).unwrap();
        assert!(matches!(
            open(&p),
            Err(WalError::Corrupt { offset: 12, .. })
        ));
    }

    #[test]
    fn a_missing_or_unknown_header_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("wal.bin");
        // A log of the previous format: records without a file header.
        let mut old = Vec::new();
        old.extend_from_slice(&3u32.to_le_bytes());
        old.extend_from_slice(&crc32fast::hash(b"one").to_le_bytes());
        old.extend_from_slice(b"one");
        std::fs::write(&p, &old).unwrap();
        let err = open(&p).err().unwrap();
        assert!(matches!(err, WalError::NotALog(_)), "{err}");
        assert!(err.to_string().contains("wal.bin"), "{err}");
        assert_eq!(std::fs::read(&p).unwrap(), old);
        std::fs::write(&p, &MAGIC[..5]).unwrap();
        assert!(matches!(open(&p), Err(WalError::NotALog(_))));
        let mut v2 = file_header().to_vec();
        v2[8..].copy_from_slice(&2u32.to_le_bytes());
        std::fs::write(&p, &v2).unwrap();
        let err = open(&p).err().unwrap();
        assert!(
            matches!(
                err,
                WalError::Version {
                    found: 2,
                    expected: 1,
                    ..
                }
            ),
            "{err}"
        );
    }

    /// A failing write or sync (a full disk) leaves the log exactly as before the append.
    #[test]
    fn a_failed_append_leaves_no_partial_record() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("wal.bin");
        let fail = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        let f = std::sync::Arc::clone(&fail);
        let probe = Probe::new(move |op, _| {
            if op == Op::Written && f.load(std::sync::atomic::Ordering::SeqCst) {
                return Err(std::io::Error::other("no space left on device (injected)"));
            }
            Ok(())
        });
        let (mut w, _) = Wal::open(&p, probe).unwrap();
        w.append(b"one").unwrap();
        let before = std::fs::read(&p).unwrap();
        fail.store(true, std::sync::atomic::Ordering::SeqCst);
        assert!(w.append(b"two").is_err());
        assert_eq!(std::fs::read(&p).unwrap(), before);
        fail.store(false, std::sync::atomic::Ordering::SeqCst);
        w.append(b"three").unwrap();
        assert_eq!(strs(&open(&p).unwrap().1), ["one", "three"]);
    }
}
