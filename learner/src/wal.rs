//! A write-ahead log of accepted episodes: each is appended and synced before the learner
//! acknowledges it, so an acknowledged episode survives a crash between checkpoints. A
//! checkpoint truncates the log. Records: length (u32 LE), CRC-32 (u32 LE), bytes. A torn last
//! record (crash mid-write) is ignored on reading.

use std::fs::{File, OpenOptions};
use std::io::{Read, Write};
use std::path::{Path, PathBuf};

/// An open log.
pub struct Wal {
    path: PathBuf,
    file: File,
}

impl Wal {
    pub fn open(path: &Path) -> std::io::Result<Self> {
        let file = OpenOptions::new().create(true).append(true).open(path)?;
        Ok(Self {
            path: path.to_path_buf(),
            file,
        })
    }

    /// Appends one record and syncs it to disk.
    pub fn append(&mut self, bytes: &[u8]) -> std::io::Result<()> {
        let mut rec = Vec::with_capacity(bytes.len() + 8);
        rec.extend_from_slice(&(bytes.len() as u32).to_le_bytes());
        rec.extend_from_slice(&crc32fast::hash(bytes).to_le_bytes());
        rec.extend_from_slice(bytes);
        self.file.write_all(&rec)?;
        self.file.sync_data()
    }

    /// Empties the log (after a checkpoint holds everything in it).
    pub fn truncate(&mut self) -> std::io::Result<()> {
        self.file.set_len(0)?;
        self.file.sync_all()
    }

    /// Every intact record, in order; stops at the first torn or corrupt one.
    pub fn read_all(path: &Path) -> std::io::Result<Vec<Vec<u8>>> {
        let mut bytes = Vec::new();
        match File::open(path) {
            Ok(mut f) => {
                f.read_to_end(&mut bytes)?;
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
            Err(e) => return Err(e),
        }
        let mut out = Vec::new();
        let mut at = 0usize;
        while at + 8 <= bytes.len() {
            let len = u32::from_le_bytes(bytes[at..at + 4].try_into().expect("4 bytes")) as usize;
            let crc = u32::from_le_bytes(bytes[at + 4..at + 8].try_into().expect("4 bytes"));
            let Some(body) = bytes.get(at + 8..at + 8 + len) else {
                break;
            };
            if crc32fast::hash(body) != crc {
                break;
            }
            out.push(body.to_vec());
            at += 8 + len;
        }
        Ok(out)
    }

    pub fn path(&self) -> &Path {
        &self.path
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn records_survive_and_a_torn_tail_is_ignored() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("wal.bin");
        let mut w = Wal::open(&p).unwrap();
        w.append(b"one").unwrap();
        w.append(b"two!").unwrap();
        assert_eq!(
            Wal::read_all(&p).unwrap(),
            vec![b"one".to_vec(), b"two!".to_vec()]
        );
        // A torn record at the end (crash mid-write).
        let mut f = OpenOptions::new().append(true).open(&p).unwrap();
        f.write_all(&[9, 0, 0, 0, 1, 2]).unwrap();
        assert_eq!(Wal::read_all(&p).unwrap().len(), 2);
        w.truncate().unwrap();
        assert!(Wal::read_all(&p).unwrap().is_empty());
        assert!(Wal::read_all(&dir.path().join("none")).unwrap().is_empty());
    }
}
