//! The frame around every file the learner writes for later (checkpoints, model files):
//! magic (8 bytes), format version (u32 LE), payload length (u64 LE), payload, CRC-32 (IEEE) of
//! the payload (u32 LE). [`open`] checks it in that order and never panics.
//!
//! [`replace`] is the one durable way to put a whole file in place (checkpoints, model files and
//! a new write-ahead log all go through it), in this order:
//!
//! 1. create the temporary file (a sibling of the target, so the rename stays in one directory),
//!    write every part, `fsync` it;
//! 2. rename it over the target;
//! 3. `fsync` the directory, which makes the rename itself survive a power loss.
//!
//! Only when all three succeeded is the new file durable, and only then may anything that it
//! supersedes be dropped (the learner truncates its write-ahead log after a checkpoint). If
//! writing or syncing fails (a full disk), the partial temporary file is removed and the target
//! is untouched.
//!
//! Every file-system step of a durable write, here and in the write-ahead log, is reported to a
//! [`Probe`] ([`Op`]), through which tests model power losses and full disks. This module is
//! the bottom of the learner's storage: `wal` and `checkpoint` stand on it, `store` on those
//! (and re-exports [`Op`] and [`Probe`] as `learner::store::{Op, Probe}`).

use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// A file-system step of a durable write, reported to a [`Probe`] right after it happened.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Op<'a> {
    /// A new empty file was created at the path (any old file there is replaced).
    Created,
    /// Bytes were written to the file (not yet synced).
    Written,
    /// The file's content and length were synced (`fsync` / `fdatasync`).
    Synced,
    /// The file's length was set (cut back), not yet synced.
    SetLen,
    /// `from` was renamed to the path (not yet durable: its directory is not synced).
    Renamed { from: &'a Path },
    /// The file was removed.
    Removed,
    /// The directory at the path was synced: its entries are durable.
    DirSynced,
}

type ProbeFn = dyn Fn(Op<'_>, &Path) -> std::io::Result<()> + Send + Sync;

/// Sees every file-system step of a durable write (a whole file put in place, the write-ahead
/// log, the store; tests model a power loss from it); an error it returns fails the step as the file
/// system would (tests inject a full disk with it). The learner runs with [`Probe::none`].
#[derive(Clone, Default)]
pub struct Probe(Option<Arc<ProbeFn>>);

impl Probe {
    pub fn none() -> Self {
        Self(None)
    }

    pub fn new(f: impl Fn(Op<'_>, &Path) -> std::io::Result<()> + Send + Sync + 'static) -> Self {
        Self(Some(Arc::new(f)))
    }

    pub(crate) fn after(&self, op: Op<'_>, path: &Path) -> std::io::Result<()> {
        match &self.0 {
            Some(f) => f(op, path),
            None => Ok(()),
        }
    }
}

impl std::fmt::Debug for Probe {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(if self.0.is_some() {
            "Probe(..)"
        } else {
            "Probe(none)"
        })
    }
}

/// Bytes before the payload.
pub(crate) const HEADER: usize = 8 + 4 + 8;

/// Why a frame does not hold a payload.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) enum FrameError {
    BadMagic,
    Version(u32),
    Truncated { got: u64, expected: u64 },
    Corrupt,
}

fn header(magic: &[u8; 8], version: u32, len: usize) -> [u8; HEADER] {
    let mut h = [0u8; HEADER];
    h[..8].copy_from_slice(magic);
    h[8..12].copy_from_slice(&version.to_le_bytes());
    h[12..].copy_from_slice(&(len as u64).to_le_bytes());
    h
}

/// The whole file in memory.
pub(crate) fn seal(magic: &[u8; 8], version: u32, payload: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(HEADER + payload.len() + 4);
    out.extend_from_slice(&header(magic, version, payload.len()));
    out.extend_from_slice(payload);
    out.extend_from_slice(&crc32fast::hash(payload).to_le_bytes());
    out
}

/// Writes the framed `payload` to `path` durably through `tmp` ([`replace`]).
pub(crate) fn write_atomic(
    path: &Path,
    tmp: &Path,
    magic: &[u8; 8],
    version: u32,
    payload: &[u8],
    probe: &Probe,
) -> Result<(), (PathBuf, std::io::Error)> {
    replace_observed(
        path,
        tmp,
        &[
            &header(magic, version, payload.len()),
            payload,
            &crc32fast::hash(payload).to_le_bytes(),
        ],
        probe,
    )
}

/// Writes `parts` one after the other to `tmp`, syncs it, renames it to `path` and syncs the
/// directory; an error names the file (or directory) it happened to.
pub(crate) fn replace(
    path: &Path,
    tmp: &Path,
    parts: &[&[u8]],
) -> Result<(), (PathBuf, std::io::Error)> {
    replace_observed(path, tmp, parts, &Probe::none())
}

/// [`replace`], reporting every step to `probe`.
pub(crate) fn replace_observed(
    path: &Path,
    tmp: &Path,
    parts: &[&[u8]],
    probe: &Probe,
) -> Result<(), (PathBuf, std::io::Error)> {
    let write = || -> std::io::Result<()> {
        let mut f = File::create(tmp)?;
        probe.after(Op::Created, tmp)?;
        for part in parts {
            f.write_all(part)?;
        }
        probe.after(Op::Written, tmp)?;
        f.sync_all()?;
        probe.after(Op::Synced, tmp)
    };
    if let Err(e) = write() {
        remove_partial(tmp, probe);
        return Err((tmp.to_path_buf(), e));
    }
    if let Err(e) = std::fs::rename(tmp, path) {
        remove_partial(tmp, probe);
        return Err((path.to_path_buf(), e));
    }
    let dir = parent(path);
    probe
        .after(Op::Renamed { from: tmp }, path)
        .and_then(|()| sync_dir(dir, probe))
        .map_err(|e| (dir.to_path_buf(), e))
}

/// Removes what a failed write left at `tmp` (best effort: the write's error is the one to
/// report).
fn remove_partial(tmp: &Path, probe: &Probe) {
    if std::fs::remove_file(tmp).is_ok() {
        let _ = probe.after(Op::Removed, tmp);
    }
}

/// The directory holding `path` (`.` for a bare file name).
pub(crate) fn parent(path: &Path) -> &Path {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    }
}

/// Makes the entries of `dir` (files created, renamed or removed in it) durable.
pub(crate) fn sync_dir(dir: &Path, probe: &Probe) -> std::io::Result<()> {
    File::open(dir)?.sync_all()?;
    probe.after(Op::DirSynced, dir)
}

/// The payload of a frame with `magic` and `version`; checks magic, length, version, size and
/// checksum, in that order.
pub(crate) fn open<'a>(
    bytes: &'a [u8],
    magic: &[u8; 8],
    version: u32,
) -> Result<&'a [u8], FrameError> {
    if bytes.len() < 8 || &bytes[..8] != magic {
        return Err(FrameError::BadMagic);
    }
    let (Some(v), Some(l)) = (bytes.get(8..12), bytes.get(12..HEADER)) else {
        return Err(FrameError::Truncated {
            got: bytes.len() as u64,
            expected: HEADER as u64,
        });
    };
    let found = u32::from_le_bytes([v[0], v[1], v[2], v[3]]);
    if found != version {
        return Err(FrameError::Version(found));
    }
    let mut len = [0u8; 8];
    len.copy_from_slice(l);
    let len = u64::from_le_bytes(len);
    let expected = (HEADER as u64).saturating_add(len).saturating_add(4);
    if bytes.len() as u64 != expected {
        return Err(FrameError::Truncated {
            got: bytes.len() as u64,
            expected,
        });
    }
    let (payload, crc) = bytes[HEADER..].split_at(len as usize);
    if crc32fast::hash(payload).to_le_bytes() != crc {
        return Err(FrameError::Corrupt);
    }
    Ok(payload)
}

#[cfg(test)]
mod tests {
    use std::sync::{Arc, Mutex};

    use super::*;

    const MAGIC: &[u8; 8] = b"FSRLTEST";

    #[test]
    fn frames_round_trip_and_every_damage_is_named() {
        let bytes = seal(MAGIC, 3, b"payload");
        assert_eq!(open(&bytes, MAGIC, 3), Ok(&b"payload"[..]));
        assert_eq!(open(&bytes, b"FSRLELSE", 3), Err(FrameError::BadMagic));
        assert_eq!(open(&bytes[..5], MAGIC, 3), Err(FrameError::BadMagic));
        assert!(matches!(
            open(&bytes[..10], MAGIC, 3),
            Err(FrameError::Truncated { got: 10, .. })
        ));
        assert_eq!(open(&bytes, MAGIC, 4), Err(FrameError::Version(3)));
        for cut in HEADER..bytes.len() {
            assert!(matches!(
                open(&bytes[..cut], MAGIC, 3),
                Err(FrameError::Truncated { .. })
            ));
        }
        let mut longer = bytes.clone();
        longer.push(0);
        assert!(matches!(
            open(&longer, MAGIC, 3),
            Err(FrameError::Truncated { .. })
        ));
        for i in HEADER..bytes.len() {
            let mut flipped = bytes.clone();
            flipped[i] ^= 0x01;
            assert_eq!(
                open(&flipped, MAGIC, 3),
                Err(FrameError::Corrupt),
                "byte {i}"
            );
        }
        // A length field near u64::MAX neither overflows nor panics.
        let mut huge = bytes.clone();
        huge[12..20].copy_from_slice(&u64::MAX.to_le_bytes());
        assert!(matches!(
            open(&huge, MAGIC, 3),
            Err(FrameError::Truncated { .. })
        ));
    }

    #[test]
    fn atomic_writes_leave_no_temporary_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("f.bin");
        let tmp = dir.path().join("f.bin.tmp");
        write_atomic(&path, &tmp, MAGIC, 1, b"abc", &Probe::none()).unwrap();
        assert!(!tmp.exists());
        assert_eq!(std::fs::read(&path).unwrap(), seal(MAGIC, 1, b"abc"));
        let err = write_atomic(
            &path,
            &dir.path().join("no/such/dir"),
            MAGIC,
            1,
            b"abc",
            &Probe::none(),
        )
        .unwrap_err();
        assert!(err.0.ends_with("no/such/dir"));
    }

    /// The order is write, sync, rename, directory sync; a failure before the rename removes
    /// the temporary file and leaves the old target as it was.
    #[test]
    fn replace_syncs_the_file_then_the_directory_and_cleans_up_after_a_failure() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("f.bin");
        let tmp = dir.path().join("f.tmp");
        let seen = Arc::new(Mutex::new(Vec::new()));
        let log = Arc::clone(&seen);
        let probe = Probe::new(move |op, p| {
            log.lock().unwrap().push(format!(
                "{op:?} {}",
                p.file_name().unwrap().to_string_lossy()
            ));
            Ok(())
        });
        replace_observed(&path, &tmp, &[b"ab", b"c"], &probe).unwrap();
        let d = dir
            .path()
            .file_name()
            .unwrap()
            .to_string_lossy()
            .into_owned();
        let tmp_s = tmp.display().to_string();
        assert_eq!(
            *seen.lock().unwrap(),
            [
                "Created f.tmp".to_string(),
                "Written f.tmp".into(),
                "Synced f.tmp".into(),
                format!("Renamed {{ from: {tmp_s:?} }} f.bin"),
                format!("DirSynced {d}"),
            ]
        );
        // A full disk while writing: the error names the temporary file, which is gone.
        let failing = Probe::new(|op, _| match op {
            Op::Written => Err(std::io::Error::other("no space left (injected)")),
            _ => Ok(()),
        });
        let err = replace_observed(&path, &tmp, &[b"new"], &failing).unwrap_err();
        assert_eq!(err.0, tmp);
        assert!(!tmp.exists());
        assert_eq!(std::fs::read(&path).unwrap(), b"abc");
    }
}
