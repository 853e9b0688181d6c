//! A run's training log, `metrics.jsonl` in its run directory, written the same way by both
//! modes (the single-process trainer and the learner process): one JSON object per line, phase
//! `"imitation"` per epoch, `"rl"` per RL episode trained (in the order trained) and
//! `"validation"` per validation; a run resumed from a checkpoint first cuts its log back to
//! that checkpoint ([`trim`]), so every episode appears once.

use std::io::Write;
use std::path::Path;
use std::time::Duration;

use serde::Serialize;

/// One RL episode's line.
#[derive(Debug, Serialize)]
pub struct RlLine<'a> {
    pub phase: &'a str,
    pub episode: u64,
    pub epsilon: f64,
    pub outcome: &'a str,
    pub steps: u32,
    pub return_sum: f64,
    pub loss: f32,
    pub success_rate_window: f64,
    pub collision_rate_window: f64,
    pub timeout_rate_window: f64,
    pub policy_version: u64,
    pub env_steps: u64,
    pub replay_size: usize,
    pub wall_s: f64,
    /// The actor that played the episode and its index in that actor's numbering (the learner
    /// process; absent in a single-process run, whose log stays as it was).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub actor: Option<u32>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub actor_episode: Option<u64>,
}

/// The imitation lines of a run's log, gathered from the warm start's progress and written
/// once it is done (both modes): each epoch's loss against the mean and variance of the
/// demonstrations' returns (an imitation loss means little without the spread of its targets).
#[derive(Debug, Default)]
pub struct ImitationLog {
    targets: (f64, f64),
    epochs: Vec<(u32, f32, f64)>,
}

impl ImitationLog {
    /// Records what `p` tells; `wall_s` is the run's clock now.
    pub fn observe(&mut self, p: &crate::imitation::ImitationProgress, wall_s: f64) {
        use crate::imitation::ImitationProgress;
        match *p {
            ImitationProgress::DemosDone {
                target_mean,
                target_var,
                ..
            } => self.targets = (target_mean, target_var),
            ImitationProgress::Epoch { done, loss, .. } => {
                self.epochs.push((done - 1, loss, wall_s))
            }
            ImitationProgress::Demo { .. } | ImitationProgress::Batch { .. } => {}
        }
    }

    /// The lines, one per epoch (phase `"imitation"`).
    pub fn lines(&self) -> impl Iterator<Item = serde_json::Value> + '_ {
        let (mean, target_var) = self.targets;
        self.epochs.iter().map(move |&(epoch, loss, wall_s)| {
            serde_json::json!({"phase": "imitation", "epoch": epoch, "loss": loss, "target_mean": mean, "target_var": target_var, "wall_s": wall_s})
        })
    }
}

/// Appends `line` and a newline in one write (a log appended to by one process at a time).
pub fn append(file: &mut std::fs::File, line: &impl Serialize) -> std::io::Result<()> {
    let mut text = serde_json::to_string(line).map_err(std::io::Error::other)?;
    text.push('\n');
    file.write_all(text.as_bytes())
}

/// The largest `wall_s` in a metrics log (zero when there is none).
pub fn last_wall(path: &Path) -> Duration {
    let text = std::fs::read_to_string(path).unwrap_or_default();
    let wall_s = text
        .lines()
        .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
        .filter_map(|v| v.get("wall_s").and_then(|w| w.as_f64()))
        .filter(|w| w.is_finite() && *w >= 0.0)
        .fold(0.0, f64::max);
    Duration::from_secs_f64(wall_s)
}

/// What a resumed run cuts from its log.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Trim {
    /// RL lines and the validations the resumed run does again (single-process: it validates
    /// after the checkpoint itself).
    RlAndValidations,
    /// RL lines only (a distributed run: its evaluator goes on from its own next validation).
    Rl,
    /// Imitation and RL lines (a run started again from nothing: no checkpoint to go on from).
    Restart,
}

/// Cuts the `metrics.jsonl` of a run resumed from a checkpoint after `rl_episodes` RL episodes
/// back to that checkpoint, and returns how many lines it dropped: the RL episodes from
/// `rl_episodes` on and (with [`Trim::RlAndValidations`]) the validations the resumed run does
/// again (those after the checkpoint; from a checkpoint straight after imitation, the one at
/// episode 0 too), which an interrupted run logged after its last checkpoint, and a line torn
/// by a crash (appended to, it would swallow the next line). Lines of other phases stay.
/// Written beside the log and renamed over it, so a crash here leaves the old log or the new one.
pub fn trim(path: &Path, rl_episodes: u64, what: Trim) -> std::io::Result<usize> {
    let text = match std::fs::read_to_string(path) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(0),
        Err(e) => return Err(e),
    };
    let keep = |line: &str| -> bool {
        let Ok(v) = serde_json::from_str::<serde_json::Value>(line) else {
            return false;
        };
        let episode = v.get("episode").and_then(|e| e.as_u64());
        match v.get("phase").and_then(|p| p.as_str()) {
            Some("rl") => episode.is_some_and(|e| e < rl_episodes),
            Some("validation") if what == Trim::RlAndValidations => {
                episode.is_some_and(|e| e < rl_episodes || (e == rl_episodes && e > 0))
            }
            Some("imitation") if what == Trim::Restart => false,
            _ => v.is_object(),
        }
    };
    let mut kept = String::with_capacity(text.len());
    let mut dropped = 0;
    for line in text.lines().filter(|l| !l.trim().is_empty()) {
        if keep(line) {
            kept.push_str(line);
            kept.push('\n');
        } else {
            dropped += 1;
        }
    }
    if dropped > 0 {
        let tmp = path.with_extension("jsonl.tmp");
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(kept.as_bytes())?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)?;
    }
    Ok(dropped)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lines(path: &Path) -> Vec<serde_json::Value> {
        std::fs::read_to_string(path)
            .unwrap()
            .lines()
            .map(|l| serde_json::from_str(l).unwrap())
            .collect()
    }

    #[test]
    fn a_log_is_cut_back_to_a_checkpoint_taken_straight_after_imitation() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("metrics.jsonl");
        let text = concat!(
            "{\"phase\":\"imitation\",\"epoch\":0,\"wall_s\":3.0}\n",
            "{\"phase\":\"imitation\",\"epoch\":1,\"wall_s\":7.0}\n",
            "{\"phase\":\"validation\",\"episode\":0,\"wall_s\":9.0}\n",
            "{\"phase\":\"rl\",\"episode\":0,\"wall_s\":10.0}\n",
            "{\"phase\":\"rl\",\"episode\":1,\"wall_s\":11.0}\n",
            "\n",
            "{\"phase\":\"rl\",\"epi",
        );
        std::fs::write(&path, text).unwrap();
        // The checkpoint after imitation: the resumed run validates episode 0 again.
        assert_eq!(trim(&path, 0, Trim::RlAndValidations).unwrap(), 4);
        let kept = lines(&path);
        assert_eq!(kept.len(), 2);
        assert!(kept.iter().all(|v| v["phase"] == "imitation"));
        assert_eq!(last_wall(&path), Duration::from_secs(7));
        // Nothing more to cut: the file is left as it is.
        assert_eq!(trim(&path, 0, Trim::RlAndValidations).unwrap(), 0);
        // No log yet: nothing to do.
        assert_eq!(
            trim(&dir.path().join("none.jsonl"), 5, Trim::Rl).unwrap(),
            0
        );
        // A distributed run keeps its evaluator's validation.
        std::fs::write(&path, text).unwrap();
        assert_eq!(trim(&path, 0, Trim::Rl).unwrap(), 3);
        assert_eq!(lines(&path)[2]["phase"], "validation");
    }

    #[test]
    fn a_later_checkpoint_keeps_its_own_validation() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("metrics.jsonl");
        let mut text = String::new();
        for k in 0..6 {
            text += &format!("{{\"phase\":\"rl\",\"episode\":{k}}}\n");
            if (k + 1) % 2 == 0 {
                text += &format!("{{\"phase\":\"validation\",\"episode\":{}}}\n", k + 1);
            }
        }
        std::fs::write(&path, text).unwrap();
        // Checkpoint after 4 episodes, written after the validation at 4.
        assert_eq!(trim(&path, 4, Trim::RlAndValidations).unwrap(), 3);
        let kept: Vec<(String, u64)> = lines(&path)
            .iter()
            .map(|v| {
                (
                    v["phase"].as_str().unwrap().to_string(),
                    v["episode"].as_u64().unwrap(),
                )
            })
            .collect();
        let expect = [
            ("rl", 0),
            ("rl", 1),
            ("validation", 2),
            ("rl", 2),
            ("rl", 3),
            ("validation", 4),
        ];
        assert_eq!(
            kept,
            expect.map(|(p, e)| (p.to_string(), e)).to_vec(),
            "episodes 4 and 5 and the validation at 6 go"
        );
    }
}
