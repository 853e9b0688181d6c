//! Event files in a directory: [`EventWriter`] appends scalars to a new file named as TensorBoard
//! names its own (`events.out.tfevents.<unix seconds>.<host>.<pid>.<n>`, numbers padded to a
//! fixed width so that files sort in the order they were started); [`read_dir`] reads every
//! scalar back.

use std::fs::File;
use std::io::{self, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{SystemTime, UNIX_EPOCH};

use crate::event::{self, Scalar};

/// Seconds since the Unix epoch, now.
pub fn now_s() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64())
}

/// Whether `name` is an event file's (TensorBoard reads files whose name contains `tfevents`).
pub fn is_event_file(name: &str) -> bool {
    name.contains("tfevents") && !name.starts_with('.')
}

fn host() -> String {
    let h = std::fs::read_to_string("/proc/sys/kernel/hostname")
        .unwrap_or_default()
        .trim()
        .replace(|c: char| !c.is_ascii_alphanumeric() && c != '-', "_");
    if h.is_empty() {
        "localhost".into()
    } else {
        h
    }
}

/// Files this process started, for the last field of their names.
static SEQ: AtomicU64 = AtomicU64::new(0);

/// An event file's name: `events.out.tfevents.<unix_s>.<host>.<pid>.<seq>`, every number
/// padded to a fixed width (10, 10 and 4 digits). TensorBoard reads a directory's files in name
/// order, so a file must sort after the files started before it: unpadded, pid 100000's file
/// sorted before pid 99999's of the same second.
pub fn file_name(unix_s: u64, host: &str, pid: u32, seq: u64) -> String {
    format!("events.out.tfevents.{unix_s:010}.{host}.{pid:010}.{seq:04}")
}

/// A new event file's name.
pub fn new_file_name() -> String {
    file_name(
        now_s() as u64,
        &host(),
        std::process::id(),
        SEQ.fetch_add(1, Ordering::Relaxed),
    )
}

/// The name a rebuild writes its new file under until the file is whole: hidden, and without
/// `tfevents` in it, as TensorBoard reads every file whose name contains `tfevents` (hidden ones
/// too).
pub fn rebuild_temp_name() -> String {
    format!(
        ".rebuild.{:010}.{:04}.tmp",
        std::process::id(),
        SEQ.fetch_add(1, Ordering::Relaxed)
    )
}

/// Whether `name` is a rebuild's temporary file ([`rebuild_temp_name`], or the
/// `.events.out.tfevents.*.tmp` of earlier versions), which only a crash leaves behind.
pub fn is_rebuild_temp(name: &str) -> bool {
    name.ends_with(".tmp")
        && (name.starts_with(".rebuild.") || name.starts_with(".events.out.tfevents."))
}

/// Removes the temporary files of rebuilds a crash interrupted from `dir`; returns how many.
pub fn remove_rebuild_temps(dir: &Path) -> io::Result<usize> {
    let rd = match std::fs::read_dir(dir) {
        Ok(rd) => rd,
        Err(e) if e.kind() == io::ErrorKind::NotFound => return Ok(0),
        Err(e) => return Err(e),
    };
    let mut n = 0;
    for entry in rd {
        let entry = entry?;
        if is_rebuild_temp(&entry.file_name().to_string_lossy()) && entry.file_type()?.is_file() {
            std::fs::remove_file(entry.path())?;
            n += 1;
        }
    }
    Ok(n)
}

/// Appends events to one file; what is written reaches the file at [`EventWriter::flush`].
pub struct EventWriter {
    file: File,
    path: PathBuf,
    buf: Vec<u8>,
}

impl EventWriter {
    /// Creates `path` (which must not exist) and writes the file-version event.
    pub fn create(path: &Path) -> io::Result<Self> {
        let file = File::options().write(true).create_new(true).open(path)?;
        let mut w = EventWriter {
            file,
            path: path.to_path_buf(),
            buf: Vec::with_capacity(4096),
        };
        event::frame(&mut w.buf, &event::file_version(now_s()));
        Ok(w)
    }

    /// A new file in `dir` (created if missing).
    pub fn create_in(dir: &Path) -> io::Result<Self> {
        std::fs::create_dir_all(dir)?;
        Self::create(&dir.join(new_file_name()))
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The file was renamed to `path`: the handle goes on writing it.
    pub fn renamed(&mut self, path: PathBuf) {
        self.path = path;
    }

    pub fn scalar(&mut self, s: &Scalar) {
        event::frame(&mut self.buf, &event::scalar(s));
    }

    pub fn session_start(&mut self, step: i64) {
        event::frame(&mut self.buf, &event::session_start(now_s(), step));
    }

    /// Writes what was added since the last flush (no sync: the files are derived data).
    pub fn flush(&mut self) -> io::Result<()> {
        if !self.buf.is_empty() {
            self.file.write_all(&self.buf)?;
            self.buf.clear();
        }
        Ok(())
    }

    /// Flushes and syncs the file to disk.
    pub fn sync(&mut self) -> io::Result<()> {
        self.flush()?;
        self.file.sync_all()
    }
}

/// The event files of `dir`, in name order (none if it does not exist).
pub fn event_files(dir: &Path) -> io::Result<Vec<PathBuf>> {
    let rd = match std::fs::read_dir(dir) {
        Ok(rd) => rd,
        Err(e) if e.kind() == io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(e) => return Err(e),
    };
    let mut files = Vec::new();
    for entry in rd {
        let entry = entry?;
        if is_event_file(&entry.file_name().to_string_lossy()) && entry.file_type()?.is_file() {
            files.push(entry.path());
        }
    }
    files.sort();
    Ok(files)
}

/// Every scalar in the event files of `dir`, file by file in name order, each file up to its
/// first torn or corrupt record.
pub fn read_dir(dir: &Path) -> io::Result<Vec<Scalar>> {
    let mut out = Vec::new();
    for path in event_files(dir)? {
        let bytes = std::fs::read(&path)?;
        for data in event::records(&bytes).0 {
            let Some(e) = event::decode(data) else {
                continue;
            };
            for (tag, value) in e.values {
                out.push(Scalar {
                    tag,
                    step: e.step,
                    value,
                    wall_time: e.wall_time,
                });
            }
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn written_scalars_read_back() {
        let dir = tempfile::tempdir().unwrap();
        let mut w = EventWriter::create_in(&dir.path().join("tb")).unwrap();
        let name = w.path().file_name().unwrap().to_string_lossy().to_string();
        assert!(name.starts_with("events.out.tfevents.") && is_event_file(&name));
        for step in 1..=3 {
            w.scalar(&Scalar {
                tag: "x".into(),
                step,
                value: step as f32 / 2.0,
                wall_time: 10.0,
            });
        }
        // Nothing on disk before the flush.
        assert!(read_dir(&dir.path().join("tb")).unwrap().is_empty());
        w.flush().unwrap();
        let back = read_dir(&dir.path().join("tb")).unwrap();
        let steps: Vec<(i64, f32)> = back.iter().map(|s| (s.step, s.value)).collect();
        assert_eq!(steps, vec![(1, 0.5), (2, 1.0), (3, 1.5)]);
        // A second file sorts after the first.
        let w2 = EventWriter::create_in(&dir.path().join("tb")).unwrap();
        let files = event_files(&dir.path().join("tb")).unwrap();
        assert_eq!(files.last().unwrap(), w2.path());
        assert!(read_dir(&dir.path().join("none")).unwrap().is_empty());
    }

    #[test]
    fn names_are_fixed_width_and_sort_by_pid_within_a_second() {
        let a = file_name(1_700_000_000, "h", 99_999, 0);
        let b = file_name(1_700_000_000, "h", 100_000, 0);
        assert_eq!(a.len(), b.len(), "{a} {b}");
        assert!(a < b, "{a} sorts after {b}");
        assert!(new_file_name().len() == file_name(0, &host(), 0, 0).len());
    }

    #[test]
    fn a_rebuilds_temporary_file_is_no_event_file_and_is_removed() {
        let tmp = rebuild_temp_name();
        assert!(!tmp.contains("tfevents") && !is_event_file(&tmp), "{tmp}");
        assert!(is_rebuild_temp(&tmp));
        let dir = tempfile::tempdir().unwrap();
        let older = format!(".{}.tmp", new_file_name());
        let kept = EventWriter::create_in(dir.path()).unwrap();
        for name in [&tmp, &older] {
            std::fs::write(dir.path().join(name), b"x").unwrap();
        }
        assert_eq!(remove_rebuild_temps(dir.path()).unwrap(), 2);
        let left: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().path())
            .collect();
        assert_eq!(left, vec![kept.path().to_path_buf()]);
        assert_eq!(remove_rebuild_temps(&dir.path().join("none")).unwrap(), 0);
    }
}
