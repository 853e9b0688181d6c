//! The learner's final figures, part of the run's record: the metrics of its last moment
//! (the replay ratio it realised, `updates_per_episode`, from the counters of its last
//! checkpoint; policy lags; time waited and trained), written durably to `learner-final.json`
//! in the run directory before the learner process exits.
//!
//! The live metrics travel best effort (a monitor that subscribed late or a busy link loses
//! some, all of a short run's), so whoever writes the run's summary (`run.json`, `launch`)
//! reads the learner's figures here, never from whichever message happened to arrive. A learner
//! removes an earlier process's file when it starts, so the file is always of the last one.

use std::path::{Path, PathBuf};

/// The file's name in the run directory.
pub const FILE_NAME: &str = "learner-final.json";

/// Why the final figures cannot be written or read.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: not the learner's final figures: {reason}")]
    Decode { path: PathBuf, reason: String },
}

/// Where the learner's final figures of the run in `run_dir` are.
pub fn path(run_dir: &Path) -> PathBuf {
    run_dir.join(FILE_NAME)
}

/// Writes `figures` as the learner's final figures, durably (a temporary file synced, renamed
/// over the old one, the directory synced).
pub fn write(run_dir: &Path, figures: &proto::Metrics) -> Result<(), RecordError> {
    let path = path(run_dir);
    let text = serde_json::to_vec_pretty(figures).map_err(|e| RecordError::Decode {
        path: path.clone(),
        reason: e.to_string(),
    })?;
    let tmp = run_dir.join(format!("{FILE_NAME}.tmp"));
    crate::frame::replace(&path, &tmp, &[&text, b"\n"])
        .map_err(|(path, source)| RecordError::Io { path, source })
}

/// The learner's final figures of the run in `run_dir`, as its last metrics message would
/// carry them.
pub fn read(run_dir: &Path) -> Result<proto::Metrics, RecordError> {
    let path = path(run_dir);
    let text = std::fs::read(&path).map_err(|source| RecordError::Io {
        path: path.clone(),
        source,
    })?;
    serde_json::from_slice(&text).map_err(|e| RecordError::Decode {
        path,
        reason: e.to_string(),
    })
}

/// Removes the figures an earlier learner process left (none is not an error).
pub fn remove_stale(run_dir: &Path) -> Result<(), RecordError> {
    let path = path(run_dir);
    match std::fs::remove_file(&path) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
            Err(RecordError::Io { path, source: e })
        }
        _ => Ok(()),
    }
}

/// Puts the learner's final figures of the run in `run_dir` in place of its newest live metrics
/// in `last` (keyed by sender, as `launch` collects them), for the run's summary and
/// `run.json`.
pub fn use_final_figures(
    run_dir: &Path,
    last: &mut std::collections::BTreeMap<String, proto::Metrics>,
) -> Result<(), RecordError> {
    let figures = read(run_dir)?;
    last.retain(|sender, _| !sender.starts_with("learner"));
    last.insert(proto::SenderId::learner().to_string(), figures);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_final_figures_round_trip_and_replace_the_live_ones() {
        let dir = tempfile::tempdir().unwrap();
        let mut m = proto::Metrics {
            env_steps: 1234,
            episodes: 6,
            wall_time_s: 12.5,
            values: Default::default(),
        };
        m.values.insert("updates_per_episode".into(), 22.0 / 6.0);
        m.values.insert("policy_lag_p95".into(), 3.0);
        write(dir.path(), &m).unwrap();
        assert_eq!(read(dir.path()).unwrap(), m);
        assert!(!dir.path().join(format!("{FILE_NAME}.tmp")).exists());

        let mut stale = proto::Metrics::default();
        stale.values.insert("updates_per_episode".into(), 1.5);
        let mut last = std::collections::BTreeMap::from([
            ("actor-0".to_string(), proto::Metrics::default()),
            ("learner-0".to_string(), stale),
        ]);
        use_final_figures(dir.path(), &mut last).unwrap();
        assert_eq!(last.len(), 2);
        assert_eq!(last["learner-0"], m);

        remove_stale(dir.path()).unwrap();
        remove_stale(dir.path()).unwrap();
        let e = read(dir.path()).unwrap_err();
        assert!(e.to_string().contains(FILE_NAME), "{e}");
        std::fs::write(path(dir.path()), "{not json").unwrap();
        assert!(matches!(read(dir.path()), Err(RecordError::Decode { .. })));
    }
}
