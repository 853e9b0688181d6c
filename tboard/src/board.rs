//! A run's TensorBoard directory (`<run>/tb/`), kept in step with the run's logs: [`RunBoard`]
//! follows `metrics.jsonl` (and `validation.jsonl`, a distributed run's learning curve while it
//! runs) and turns each new line into scalars; it takes live metrics messages too
//! ([`RunBoard::live`]). Each tag's steps only go up: a point at or below a tag's last step is
//! not written again, so a line seen twice (a validation copied from `validation.jsonl` into
//! `metrics.jsonl`) or a live value at an unchanged episode count is written once.
//!
//! A resumed run cuts its log back to its checkpoint (`learner::runlog::trim`) and trains those
//! episodes again. The board notices (on opening, or when the log is replaced or shrinks) and
//! *rebuilds* the directory: one new file with the scalars of the log as it now is, plus the
//! live-only points of the old files up to the log's RL episodes, then the old files are
//! removed, so TensorBoard shows one curve and no step twice. The new file starts with a
//! session-start event at step 0, which makes a TensorBoard that had read the old files forget
//! them. A crash between the new file and the removal leaves both; the next rebuild merges them
//! (for each tag and step the later file's value).

use std::collections::HashMap;
use std::io::{self, Read, Seek, SeekFrom};
use std::os::unix::fs::MetadataExt;
use std::path::{Path, PathBuf};

use proto::{Metrics, SenderId};

use crate::event::Scalar;
use crate::tags::{self, LiveMapper, LogMapper, Mode, Point};
use crate::writer::{self, now_s, EventWriter};

/// The files a board follows, in the order they are read.
pub const LOGS: [&str; 2] = ["metrics.jsonl", "validation.jsonl"];

/// A followed log: the file's identity and how far it was read.
#[derive(Debug, Default)]
struct Follow {
    path: PathBuf,
    id: Option<(u64, u64)>,
    offset: u64,
    partial: Vec<u8>,
}

impl Follow {
    /// The complete lines added since the last read; `Err(true)` if the file was replaced or
    /// cut (the board must rebuild).
    fn read_new(&mut self) -> Result<Vec<serde_json::Value>, io::Result<()>> {
        let mut f = match std::fs::File::open(&self.path) {
            Ok(f) => f,
            Err(e) if e.kind() == io::ErrorKind::NotFound => {
                return if self.id.is_some() {
                    Err(Ok(()))
                } else {
                    Ok(Vec::new())
                };
            }
            Err(e) => return Err(Err(e)),
        };
        let meta = f.metadata().map_err(Err)?;
        let id = (meta.dev(), meta.ino());
        if self.id.is_some_and(|old| old != id) || meta.len() < self.offset {
            return Err(Ok(()));
        }
        self.id = Some(id);
        if meta.len() == self.offset {
            return Ok(Vec::new());
        }
        f.seek(SeekFrom::Start(self.offset)).map_err(Err)?;
        let mut bytes = Vec::new();
        f.read_to_end(&mut bytes).map_err(Err)?;
        self.offset += bytes.len() as u64;
        self.partial.extend_from_slice(&bytes);
        let Some(end) = self.partial.iter().rposition(|&b| b == b'\n') else {
            return Ok(Vec::new());
        };
        let complete: Vec<u8> = self.partial.drain(..=end).collect();
        Ok(String::from_utf8_lossy(&complete)
            .lines()
            .filter_map(|l| serde_json::from_str(l).ok())
            .collect())
    }
}

/// A run's TensorBoard directory, fed from its logs and live metrics.
pub struct RunBoard {
    dir: PathBuf,
    mode: Mode,
    follows: Vec<Follow>,
    mapper: LogMapper,
    live: LiveMapper,
    writer: EventWriter,
    last: HashMap<String, i64>,
}

impl RunBoard {
    /// The board of the run in `run_dir`, writing `run_dir/tb/`: rebuilt from the logs as they
    /// are now if it holds files already (a resumed run).
    pub fn open(run_dir: &Path, mode: Mode) -> io::Result<Self> {
        let follows = LOGS
            .iter()
            .map(|name| Follow {
                path: run_dir.join(name),
                ..Default::default()
            })
            .collect();
        let dir = run_dir.join("tb");
        let writer = EventWriter::create_in(&dir)?;
        let mut b = RunBoard {
            dir,
            mode,
            follows,
            mapper: LogMapper::new(mode),
            live: LiveMapper::not_in_log(),
            writer,
            last: HashMap::new(),
        };
        b.rebuild()?;
        Ok(b)
    }

    /// The directory written.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Reads what the logs gained and writes it; rebuilds if a log was replaced or cut.
    pub fn poll(&mut self) -> io::Result<()> {
        let mut points = Vec::new();
        for i in 0..self.follows.len() {
            match self.follows[i].read_new() {
                Ok(lines) => {
                    for v in &lines {
                        points.extend(self.mapper.line(v));
                    }
                }
                Err(Ok(())) => return self.rebuild(),
                Err(Err(e)) => return Err(e),
            }
        }
        self.write(points, now_s());
        self.writer.flush()
    }

    /// Takes one live metrics message (only what the logs do not hold: [`tags::is_live`]).
    pub fn live(&mut self, sender: SenderId, m: &Metrics) -> io::Result<()> {
        if let Mode::SingleProcess { .. } = self.mode {
            return Ok(());
        }
        let points = self.live.message(sender, m);
        if points.is_empty() {
            return Ok(());
        }
        self.write(points, now_s());
        self.writer.flush()
    }

    /// Writes each point above its tag's last step.
    fn write(&mut self, points: Vec<Point>, wall_time: f64) {
        for (tag, step, value) in points {
            let last = self.last.entry(tag.clone()).or_insert(i64::MIN);
            if step <= *last {
                continue;
            }
            *last = step;
            self.writer.scalar(&Scalar {
                tag,
                step,
                value: value as f32,
                wall_time,
            });
        }
    }

    /// Writes the directory again from the logs as they are (see the module's page).
    fn rebuild(&mut self) -> io::Result<()> {
        let own = self.writer.path().to_path_buf();
        let old_files: Vec<PathBuf> = writer::event_files(&self.dir)?
            .into_iter()
            .filter(|p| *p != own)
            .collect();
        // What the old files hold, for each (tag, step) the last value (and its time).
        let mut old: Vec<Scalar> = Vec::new();
        for path in &old_files {
            old.extend(read_file(path)?);
        }
        old.extend(read_file(&own)?);
        // Something was written: a TensorBoard may have read it.
        let resumed = !old.is_empty();
        // The logs from their start.
        self.mapper = LogMapper::new(self.mode);
        let mut points = Vec::new();
        let mut rl_done: i64 = 0;
        for f in &mut self.follows {
            *f = Follow {
                path: f.path.clone(),
                ..Default::default()
            };
            for v in f.read_new().unwrap_or_default() {
                if v.get("phase").and_then(|p| p.as_str()) == Some("rl") {
                    if let Some(e) = v.get("episode").and_then(|e| e.as_i64()) {
                        rl_done = rl_done.max(e + 1);
                    }
                }
                points.extend(self.mapper.line(&v));
            }
        }
        let times: HashMap<(String, i64), f64> = old
            .iter()
            .map(|s| ((s.tag.clone(), s.step), s.wall_time))
            .collect();
        let now = now_s();
        let mut merged: Vec<Scalar> = Vec::new();
        let mut at: HashMap<(String, i64), usize> = HashMap::new();
        let live_kept = old.into_iter().filter(|s| {
            self.mode == Mode::Distributed && tags::is_live(&s.tag) && s.step <= rl_done
        });
        let from_log = points.into_iter().map(|(tag, step, value)| Scalar {
            wall_time: times.get(&(tag.clone(), step)).copied().unwrap_or(now),
            tag,
            step,
            value: value as f32,
        });
        for s in live_kept.chain(from_log) {
            match at.get(&(s.tag.clone(), s.step)) {
                Some(&i) => merged[i] = s,
                None => {
                    at.insert((s.tag.clone(), s.step), merged.len());
                    merged.push(s);
                }
            }
        }
        merged.sort_by_key(|s| s.step);
        // The new file: written whole under a name TensorBoard ignores, then renamed.
        let tmp = self.dir.join(format!(".{}.tmp", writer::new_file_name()));
        let mut w = EventWriter::create(&tmp)?;
        if resumed {
            w.session_start(0);
        }
        self.last.clear();
        for s in &merged {
            w.scalar(s);
            let last = self.last.entry(s.tag.clone()).or_insert(i64::MIN);
            *last = (*last).max(s.step);
        }
        w.sync()?;
        let path = self.dir.join(writer::new_file_name());
        std::fs::rename(&tmp, &path)?;
        w.renamed(path);
        for p in old_files.iter().chain([&own]) {
            std::fs::remove_file(p)?;
        }
        self.writer = w;
        Ok(())
    }
}

fn read_file(path: &Path) -> io::Result<Vec<Scalar>> {
    let bytes = match std::fs::read(path) {
        Ok(b) => b,
        Err(e) if e.kind() == io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(e) => return Err(e),
    };
    let mut out = Vec::new();
    for data in crate::event::records(&bytes).0 {
        if let Some(e) = crate::event::decode(data) {
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

/// A [`RunBoard`] that never stops a training: the first error is said on stderr and the
/// board stops there (the files are a view of the logs, which go on). Polls at most every
/// [`Keeper::POLL`] ([`Keeper::tick`]), so it can sit in any loop.
pub struct Keeper {
    board: Option<RunBoard>,
    last_poll: Option<std::time::Instant>,
}

impl Keeper {
    pub const POLL: std::time::Duration = std::time::Duration::from_millis(500);

    pub fn open(run_dir: &Path, mode: Mode) -> Self {
        let board = RunBoard::open(run_dir, mode)
            .map_err(|e| warn(&run_dir.join("tb"), e))
            .ok();
        Keeper {
            board,
            last_poll: None,
        }
    }

    fn with(&mut self, f: impl FnOnce(&mut RunBoard) -> io::Result<()>) {
        if let Some(b) = &mut self.board {
            if let Err(e) = f(b) {
                warn(b.dir(), e);
                self.board = None;
            }
        }
    }

    /// Polls the logs if the last poll is [`Keeper::POLL`] ago.
    pub fn tick(&mut self) {
        if self.last_poll.is_none_or(|t| t.elapsed() >= Self::POLL) {
            self.last_poll = Some(std::time::Instant::now());
            self.with(RunBoard::poll);
        }
    }

    /// Polls the logs now (at the end of a run).
    pub fn finish(&mut self) {
        self.with(RunBoard::poll);
    }

    pub fn live(&mut self, sender: SenderId, m: &Metrics) {
        self.with(|b| b.live(sender, m));
    }
}

fn warn(dir: &Path, e: io::Error) {
    eprintln!(
        "warning: TensorBoard files in {}: {e}; no more are written (the run goes on)",
        dir.display()
    );
}

/// A [`Keeper`] on a thread of its own, polling until dropped (then once more): for a run
/// whose loop is not ours (`fsrl train --single-process`).
pub struct Follower {
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Follower {
    pub fn spawn(run_dir: &Path, mode: Mode) -> Self {
        use std::sync::atomic::Ordering;
        let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        let run_dir = run_dir.to_path_buf();
        let flag = stop.clone();
        let thread = std::thread::Builder::new()
            .name("tensorboard".into())
            .spawn(move || {
                let mut k = Keeper::open(&run_dir, mode);
                while !flag.load(Ordering::Relaxed) {
                    std::thread::park_timeout(Keeper::POLL);
                    k.tick();
                }
                k.finish();
            })
            .ok();
        Follower { stop, thread }
    }
}

impl Drop for Follower {
    fn drop(&mut self) {
        self.stop.store(true, std::sync::atomic::Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            t.thread().unpark();
            let _ = t.join();
        }
    }
}

/// A TensorBoard directory fed only from live metrics (`fsrl watch --tensorboard`): every tag
/// [`LiveMapper::all`] gives. Opened on a directory with files already, it goes on above each
/// tag's last step there, so watching a run again adds no step twice.
pub struct LiveBoard {
    mapper: LiveMapper,
    writer: EventWriter,
    last: HashMap<String, i64>,
}

impl LiveBoard {
    pub fn open(dir: &Path) -> io::Result<Self> {
        let mut last = HashMap::new();
        for s in writer::read_dir(dir)? {
            let l = last.entry(s.tag).or_insert(i64::MIN);
            *l = (*l).max(s.step);
        }
        Ok(LiveBoard {
            mapper: LiveMapper::all(),
            writer: EventWriter::create_in(dir)?,
            last,
        })
    }

    /// The file written.
    pub fn path(&self) -> &Path {
        self.writer.path()
    }

    /// Writes the points of one message; returns how many.
    pub fn message(&mut self, sender: SenderId, m: &Metrics) -> io::Result<usize> {
        let mut n = 0;
        let now = now_s();
        for (tag, step, value) in self.mapper.message(sender, m) {
            let last = self.last.entry(tag.clone()).or_insert(i64::MIN);
            if step <= *last {
                continue;
            }
            *last = step;
            self.writer.scalar(&Scalar {
                tag,
                step,
                value: value as f32,
                wall_time: now,
            });
            n += 1;
        }
        self.writer.flush()?;
        Ok(n)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proto::Role;
    use std::io::Write;

    fn rl(e: u64, loss: f64) -> String {
        format!(
            "{{\"phase\":\"rl\",\"episode\":{e},\"loss\":{loss},\"wall_s\":{}}}\n",
            e as f64
        )
    }

    fn append(path: &Path, text: &str) {
        let mut f = std::fs::File::options()
            .create(true)
            .append(true)
            .open(path)
            .unwrap();
        f.write_all(text.as_bytes()).unwrap();
    }

    /// `tag`'s (step, value) points in the directory, in file order.
    fn points(dir: &Path, tag: &str) -> Vec<(i64, f32)> {
        writer::read_dir(&dir.join("tb"))
            .unwrap()
            .into_iter()
            .filter(|s| s.tag == tag)
            .map(|s| (s.step, s.value))
            .collect()
    }

    const SINGLE: Mode = Mode::SingleProcess {
        updates_per_episode: 20.0,
    };

    #[test]
    fn new_lines_are_written_as_they_come_and_each_step_once() {
        let run = tempfile::tempdir().unwrap();
        let metrics = run.path().join("metrics.jsonl");
        let mut b = RunBoard::open(run.path(), SINGLE).unwrap();
        b.poll().unwrap();
        append(&metrics, &rl(0, 0.5));
        // Half a line waits for its end.
        let line = rl(1, 0.25);
        append(&metrics, &line[..10]);
        b.poll().unwrap();
        assert_eq!(points(run.path(), tags::TD_LOSS), vec![(1, 0.5)]);
        append(&metrics, &line[10..]);
        b.poll().unwrap();
        assert_eq!(points(run.path(), tags::TD_LOSS), vec![(1, 0.5), (2, 0.25)]);
        assert_eq!(
            points(run.path(), tags::ACTORS_ALIVE),
            vec![(1, 1.0), (2, 1.0)]
        );
        // A validation in both logs (a distributed run copies it at the end): written once.
        let val = "{\"phase\":\"validation\",\"episode\":2,\"success_rate\":0.5,\"collision_rate\":0.5,\"timeout_rate\":0.0,\"discomfort\":0.1,\"nav_time_s\":12.0,\"mean_return\":0.3}\n";
        append(&run.path().join("validation.jsonl"), val);
        b.poll().unwrap();
        append(&metrics, val);
        b.poll().unwrap();
        assert_eq!(points(run.path(), tags::VAL_NAV_TIME), vec![(2, 12.0)]);
        assert_eq!(
            writer::event_files(&run.path().join("tb")).unwrap().len(),
            1
        );
    }

    #[test]
    fn a_log_cut_back_by_a_resume_is_rebuilt_into_one_curve() {
        let run = tempfile::tempdir().unwrap();
        let metrics = run.path().join("metrics.jsonl");
        let mut b = RunBoard::open(run.path(), Mode::Distributed).unwrap();
        let learner = SenderId::new(Role::Learner, 0);
        for e in 0..6 {
            append(&metrics, &rl(e, 1.0));
            b.poll().unwrap();
            let m = Metrics {
                episodes: e + 1,
                values: [("imitation_done", 1.0), ("actors_alive", 2.0)]
                    .map(|(k, v)| (k.to_string(), v))
                    .into(),
                ..Default::default()
            };
            b.live(learner, &m).unwrap();
        }
        assert_eq!(points(run.path(), tags::TD_LOSS).len(), 6);
        drop(b);
        // The run stopped; its checkpoint holds 3 episodes: the log is cut back to them
        // (written beside and renamed over, as `learner::runlog::trim` does).
        let tmp = run.path().join("metrics.jsonl.tmp");
        std::fs::write(&tmp, (0..3).map(|e| rl(e, 1.0)).collect::<String>()).unwrap();
        std::fs::rename(&tmp, &metrics).unwrap();
        let mut b = RunBoard::open(run.path(), Mode::Distributed).unwrap();
        assert_eq!(
            points(run.path(), tags::TD_LOSS),
            vec![(1, 1.0), (2, 1.0), (3, 1.0)]
        );
        // The live points up to the checkpoint stay.
        assert_eq!(
            points(run.path(), tags::ACTORS_ALIVE),
            vec![(1, 2.0), (2, 2.0), (3, 2.0)]
        );
        // The resumed run trains episodes 3.. again, with other losses.
        for e in 3..5 {
            append(&metrics, &rl(e, 2.0));
        }
        b.poll().unwrap();
        assert_eq!(
            points(run.path(), tags::TD_LOSS),
            vec![(1, 1.0), (2, 1.0), (3, 1.0), (4, 2.0), (5, 2.0)]
        );
        // The same while running: a log replaced under a board is noticed at the next poll.
        let tmp = run.path().join("metrics.jsonl.tmp");
        std::fs::write(&tmp, (0..2).map(|e| rl(e, 1.0)).collect::<String>()).unwrap();
        std::fs::rename(&tmp, &metrics).unwrap();
        b.poll().unwrap();
        assert_eq!(points(run.path(), tags::TD_LOSS), vec![(1, 1.0), (2, 1.0)]);
        let files = writer::event_files(&run.path().join("tb")).unwrap();
        assert_eq!(files.len(), 1, "{files:?}");
        // A rebuilt file tells a running TensorBoard to forget the old one.
        let bytes = std::fs::read(&files[0]).unwrap();
        let events: Vec<_> = crate::event::records(&bytes)
            .0
            .into_iter()
            .map(|r| crate::event::decode(r).unwrap())
            .collect();
        assert!(events[0].file_version.is_some());
        assert!(events[1].session_start);
    }

    #[test]
    fn a_live_board_goes_on_above_the_steps_it_finds() {
        let dir = tempfile::tempdir().unwrap();
        let learner = SenderId::new(Role::Learner, 0);
        let m = |episodes: u64| Metrics {
            episodes,
            wall_time_s: episodes as f64,
            values: [("imitation_done", 1.0), ("loss", 0.5)]
                .map(|(k, v)| (k.to_string(), v))
                .into(),
            ..Default::default()
        };
        let mut b = LiveBoard::open(dir.path()).unwrap();
        assert!(b.message(learner, &m(3)).unwrap() > 0);
        assert_eq!(b.message(learner, &m(3)).unwrap(), 0);
        let mut b = LiveBoard::open(dir.path()).unwrap();
        assert_eq!(b.message(learner, &m(2)).unwrap(), 0);
        assert!(b.message(learner, &m(4)).unwrap() > 0);
        let steps: Vec<i64> = writer::read_dir(dir.path())
            .unwrap()
            .into_iter()
            .filter(|s| s.tag == tags::TD_LOSS)
            .map(|s| s.step)
            .collect();
        assert_eq!(steps, vec![3, 4]);
    }
}
