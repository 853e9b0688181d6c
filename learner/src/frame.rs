//! The frame around every file the learner writes for later (checkpoints, model files):
//! magic (8 bytes), format version (u32 LE), payload length (u64 LE), payload, CRC-32 (IEEE) of
//! the payload (u32 LE). [`write_atomic`] writes it to a temporary name, syncs and renames, so a
//! crash never leaves a half-written file; [`open`] checks it in that order and never panics.

use std::io::Write;
use std::path::Path;

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

/// Writes the framed `payload` to `tmp`, syncs it and renames it to `path`.
pub(crate) fn write_atomic(
    path: &Path,
    tmp: &Path,
    magic: &[u8; 8],
    version: u32,
    payload: &[u8],
) -> Result<(), (std::path::PathBuf, std::io::Error)> {
    replace(
        path,
        tmp,
        &[
            &header(magic, version, payload.len()),
            payload,
            &crc32fast::hash(payload).to_le_bytes(),
        ],
    )
}

/// Writes `parts` one after the other to `tmp`, syncs it and renames it to `path`; an error
/// names the file it happened to.
pub(crate) fn replace(
    path: &Path,
    tmp: &Path,
    parts: &[&[u8]],
) -> Result<(), (std::path::PathBuf, std::io::Error)> {
    let write = || -> std::io::Result<()> {
        let mut f = std::fs::File::create(tmp)?;
        for part in parts {
            f.write_all(part)?;
        }
        f.sync_all()
    };
    write().map_err(|e| (tmp.to_path_buf(), e))?;
    std::fs::rename(tmp, path).map_err(|e| (path.to_path_buf(), e))
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
        write_atomic(&path, &tmp, MAGIC, 1, b"abc").unwrap();
        assert!(!tmp.exists());
        assert_eq!(std::fs::read(&path).unwrap(), seal(MAGIC, 1, b"abc"));
        let err =
            write_atomic(&path, &dir.path().join("no/such/dir"), MAGIC, 1, b"abc").unwrap_err();
        assert!(err.0.ends_with("no/such/dir"));
    }
}
