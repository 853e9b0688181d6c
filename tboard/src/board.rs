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
//! them. The new file is written under a name TensorBoard does not read
//! ([`writer::rebuild_temp_name`]) and renamed when whole; such a file left by a crash is removed
//! when a board opens. A crash between the rename and the removal leaves both event files; the
//! next rebuild merges them (for each tag and step the later file's value).
//!
//! A point's wall time is its log line's `wall_s` (the run's clock: seconds of training, going
//! on across resumes) on a [`Clock`] anchored when the board (re)builds, so a rebuilt file keeps
//! the run's own timing rather than the rebuild's.

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

/// The run's clock as wall times: a log line's `wall_s` (seconds of training, the learner's
/// clock, which a resumed run goes on from its log) becomes `anchor + wall_s`, the anchor chosen
/// at a (re)build so that the log's latest time is then. A distributed run's validation lines
/// carry the evaluator's clock instead (it starts again with the evaluator): a validation takes
/// the time of the RL episode it followed.
#[derive(Debug, Default)]
struct Clock {
    anchor: f64,
    /// `wall_s` of the RL line of each step (episode + 1).
    rl: HashMap<i64, f64>,
    /// The latest `wall_s` on the learner's clock.
    latest: Option<f64>,
}

impl Clock {
    /// A line's `wall_s` on the learner's clock (`None`: the line has none, or another clock's).
    fn learner_s(mode: Mode, v: &serde_json::Value) -> Option<f64> {
        let phase = v.get("phase").and_then(|p| p.as_str());
        if mode == Mode::Distributed && phase == Some("validation") {
            return None;
        }
        v.get("wall_s")
            .and_then(|w| w.as_f64())
            .filter(|w| w.is_finite() && *w >= 0.0)
    }

    /// A clock whose `lines`' latest time is `now`.
    fn anchored(mode: Mode, lines: &[serde_json::Value], now: f64) -> Self {
        let latest = lines
            .iter()
            .filter_map(|v| Self::learner_s(mode, v))
            .fold(0.0, f64::max);
        Clock {
            anchor: now - latest,
            ..Default::default()
        }
    }

    /// The wall time of line `v`'s points (`now` for a line that tells none).
    fn of(&mut self, mode: Mode, v: &serde_json::Value, now: f64) -> f64 {
        let phase = v.get("phase").and_then(|p| p.as_str());
        let step = v.get("episode").and_then(|e| e.as_i64());
        let own = Self::learner_s(mode, v);
        if let Some(w) = own {
            self.latest = Some(self.latest.map_or(w, |l| l.max(w)));
            if let (Some("rl"), Some(e)) = (phase, step) {
                self.rl.insert(e + 1, w);
            }
        }
        let s = if mode == Mode::Distributed && phase == Some("validation") {
            step.and_then(|e| self.rl.get(&e).copied()).or(self.latest)
        } else {
            own
        };
        s.map_or(now, |s| self.anchor + s)
    }

    /// The wall time of a live point at `step`: that of the RL episode of the step, if known.
    fn at_step(&self, step: i64) -> Option<f64> {
        self.rl.get(&step).map(|s| self.anchor + s)
    }
}

/// A run's TensorBoard directory, fed from its logs and live metrics.
pub struct RunBoard {
    dir: PathBuf,
    mode: Mode,
    follows: Vec<Follow>,
    mapper: LogMapper,
    live: LiveMapper,
    clock: Clock,
    writer: EventWriter,
    last: HashMap<String, i64>,
}

impl RunBoard {
    /// The board of the run in `run_dir`, writing `run_dir/tb/`: rebuilt from the logs as they
    /// are now if it holds files already (a resumed run), without the temporary files of
    /// rebuilds a crash interrupted.
    pub fn open(run_dir: &Path, mode: Mode) -> io::Result<Self> {
        let follows = LOGS
            .iter()
            .map(|name| Follow {
                path: run_dir.join(name),
                ..Default::default()
            })
            .collect();
        let dir = run_dir.join("tb");
        writer::remove_rebuild_temps(&dir)?;
        let writer = EventWriter::create_in(&dir)?;
        let mut b = RunBoard {
            dir,
            mode,
            follows,
            mapper: LogMapper::new(mode),
            live: LiveMapper::not_in_log(),
            clock: Clock::default(),
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
        let now = now_s();
        for i in 0..self.follows.len() {
            match self.follows[i].read_new() {
                Ok(lines) => {
                    for v in &lines {
                        let t = self.clock.of(self.mode, v, now);
                        points.extend(self.mapper.line(v).into_iter().map(|p| (p, t)));
                    }
                }
                Err(Ok(())) => return self.rebuild(),
                Err(Err(e)) => return Err(e),
            }
        }
        self.write(points);
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
        let now = now_s();
        self.write(points.into_iter().map(|p| (p, now)).collect());
        self.writer.flush()
    }

    /// Writes each point above its tag's last step, at its wall time.
    fn write(&mut self, points: Vec<(Point, f64)>) {
        for ((tag, step, value), wall_time) in points {
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
        // The logs from their start, on the run's clock.
        self.mapper = LogMapper::new(self.mode);
        let mut lines = Vec::new();
        for f in &mut self.follows {
            *f = Follow {
                path: f.path.clone(),
                ..Default::default()
            };
            lines.extend(f.read_new().unwrap_or_default());
        }
        let now = now_s();
        self.clock = Clock::anchored(self.mode, &lines, now);
        let mut points = Vec::new();
        let mut rl_done: i64 = 0;
        for v in &lines {
            if v.get("phase").and_then(|p| p.as_str()) == Some("rl") {
                if let Some(e) = v.get("episode").and_then(|e| e.as_i64()) {
                    rl_done = rl_done.max(e + 1);
                }
            }
            let t = self.clock.of(self.mode, v, now);
            points.extend(self.mapper.line(v).into_iter().map(|p| (p, t)));
        }
        let mut merged: Vec<Scalar> = Vec::new();
        let mut at: HashMap<(String, i64), usize> = HashMap::new();
        let clock = &self.clock;
        let live_kept = old
            .into_iter()
            .filter(|s| {
                self.mode == Mode::Distributed && tags::is_live(&s.tag) && s.step <= rl_done
            })
            .map(|s| Scalar {
                wall_time: clock.at_step(s.step).unwrap_or(s.wall_time),
                ..s
            });
        let from_log = points
            .into_iter()
            .map(|((tag, step, value), wall_time)| Scalar {
                wall_time,
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
        let tmp = self.dir.join(writer::rebuild_temp_name());
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

    /// `tag`'s points in the directory, in file order, each as `field` of it with its step.
    fn series<T>(dir: &Path, tag: &str, field: fn(&Scalar) -> T) -> Vec<(i64, T)> {
        writer::read_dir(&dir.join("tb"))
            .unwrap()
            .iter()
            .filter(|s| s.tag == tag)
            .map(|s| (s.step, field(s)))
            .collect()
    }

    /// `tag`'s (step, value) points in the directory, in file order.
    fn points(dir: &Path, tag: &str) -> Vec<(i64, f32)> {
        series(dir, tag, |s| s.value)
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

    /// An RL line of episode `e` at `wall_s` on the run's clock.
    fn rl_at(e: u64, wall_s: f64) -> String {
        format!("{{\"phase\":\"rl\",\"episode\":{e},\"loss\":1.0,\"wall_s\":{wall_s}}}\n")
    }

    /// `tag`'s (step, wall time) points in the directory.
    fn times(dir: &Path, tag: &str) -> Vec<(i64, f64)> {
        series(dir, tag, |s| s.wall_time)
    }

    /// The points' wall times less the first's, against the log's `wall_s` less the first's.
    fn assert_on_the_log_clock(got: &[(i64, f64)], wall_s: &[f64]) {
        let t: Vec<f64> = got.iter().map(|p| p.1).collect();
        testkit::assert_same_spacing(&t, wall_s, &format!("the event files {got:?}"));
    }

    /// Issue 52: a rebuilt file's points keep the run's timing (each its log line's `wall_s`);
    /// before, every point the old files did not hold got the rebuild's time (a run whose
    /// board started at a resume: one instant for the whole curve).
    #[test]
    fn points_keep_the_logs_own_clock_through_rebuilds() {
        let run = tempfile::tempdir().unwrap();
        let metrics = run.path().join("metrics.jsonl");
        let walls = [3.0, 13.0, 23.5, 40.0, 41.0];
        for (e, w) in walls.iter().enumerate().take(4) {
            append(&metrics, &rl_at(e as u64, *w));
        }
        let mut b = RunBoard::open(run.path(), SINGLE).unwrap();
        assert_on_the_log_clock(&times(run.path(), tags::TD_LOSS), &walls[..4]);
        let opened = now_s();
        let last = times(run.path(), tags::TD_LOSS)[3].1;
        assert!(
            (last - opened).abs() < 60.0,
            "the log's latest point is about now"
        );
        append(&metrics, &rl_at(4, walls[4]));
        b.poll().unwrap();
        assert_on_the_log_clock(&times(run.path(), tags::TD_LOSS), &walls);
        drop(b);
        // A resume cuts the log back to 2 episodes and trains on: its clock goes on from 13.
        let tmp = run.path().join("metrics.jsonl.tmp");
        std::fs::write(&tmp, rl_at(0, walls[0]) + &rl_at(1, walls[1])).unwrap();
        std::fs::rename(&tmp, &metrics).unwrap();
        let mut b = RunBoard::open(run.path(), SINGLE).unwrap();
        append(&metrics, &rl_at(2, 14.5));
        b.poll().unwrap();
        assert_on_the_log_clock(&times(run.path(), tags::TD_LOSS), &[3.0, 13.0, 14.5]);

        // A distributed run's validation carries the evaluator's clock: it takes the time of
        // the RL episode it followed.
        let run = tempfile::tempdir().unwrap();
        let metrics = run.path().join("metrics.jsonl");
        for (e, w) in walls.iter().enumerate() {
            append(&metrics, &rl_at(e as u64, *w));
        }
        append(
            &metrics,
            "{\"phase\":\"validation\",\"episode\":2,\"success_rate\":0.5,\"wall_s\":0.25}\n",
        );
        RunBoard::open(run.path(), Mode::Distributed).unwrap();
        let rl = times(run.path(), tags::TD_LOSS);
        assert_eq!(times(run.path(), tags::VAL_SUCCESS), vec![(2, rl[1].1)]);
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
