//! Reading a run's `metrics.jsonl` (one JSON object per line, written by `fsrl train`): phase
//! `"imitation"` lines `{epoch, loss, wall_s}`, phase `"rl"` lines `{episode, epsilon, outcome,
//! steps, return_sum, loss, success_rate_window, ...}` and phase `"validation"` lines `{episode,
//! success_rate, collision_rate, timeout_rate, discomfort, nav_time_s, wall_s, ...}` (the greedy
//! policy on fixed validation seeds every so many RL episodes). Lines of other phases are skipped
//! (newer writers may add some); blank lines are ignored; anything else malformed is an error
//! naming the file and the line.
//!
//! A resumed run repeats the episodes (and epochs) done after its last checkpoint: of lines with
//! the same phase and number the last one counts, and every phase comes back sorted by number.

use std::path::Path;

use serde::Deserialize;

use crate::VizError;

/// One imitation epoch.
#[derive(Debug, Clone, PartialEq, Deserialize)]
pub struct ImitationPoint {
    pub epoch: u32,
    /// `null` in the file when the loss was not finite.
    pub loss: Option<f64>,
    #[serde(default)]
    pub wall_s: f64,
}

/// One RL episode.
#[derive(Debug, Clone, PartialEq, Deserialize)]
pub struct RlPoint {
    pub episode: u64,
    pub epsilon: f64,
    pub outcome: String,
    pub steps: u32,
    pub return_sum: f64,
    pub loss: Option<f64>,
    pub success_rate_window: f64,
    pub collision_rate_window: f64,
    pub timeout_rate_window: f64,
    #[serde(default)]
    pub policy_version: u64,
    #[serde(default)]
    pub env_steps: u64,
    #[serde(default)]
    pub wall_s: f64,
}

/// One validation: the greedy policy on the run's validation seeds after `episode` RL episodes.
#[derive(Debug, Clone, PartialEq, Deserialize)]
pub struct ValidationPoint {
    /// RL episodes trained before this validation.
    pub episode: u64,
    pub success_rate: f64,
    pub collision_rate: f64,
    pub timeout_rate: f64,
    /// Disc.: danger steps / all simulated steps.
    pub discomfort: f64,
    /// Mean over successful episodes; `null` in the file when none succeeded.
    #[serde(default)]
    pub nav_time_s: Option<f64>,
    #[serde(default)]
    pub mean_return: Option<f64>,
    /// Validation episodes.
    #[serde(default)]
    pub episodes: u32,
    #[serde(default)]
    pub seed_start: u64,
    #[serde(default)]
    pub policy_version: u64,
    #[serde(default)]
    pub env_steps: u64,
    /// Wall-clock seconds of training (resumptions add up) when the validation ended.
    #[serde(default)]
    pub wall_s: f64,
}

/// A whole metrics log.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Metrics {
    pub imitation: Vec<ImitationPoint>,
    pub rl: Vec<RlPoint>,
    pub validation: Vec<ValidationPoint>,
    /// The log's last line was cut short (not JSON, no newline after it: a run stopped while
    /// writing it) and was left out; readers say so.
    pub torn_last_line: bool,
}

/// Keeps the last of the points with the same key, sorted by key.
fn last_per_key<T>(points: &mut Vec<T>, key: impl Fn(&T) -> u64) {
    // A stable sort keeps the file order among equal keys; the last of each run of equal keys
    // is the one written last.
    points.sort_by_key(&key);
    let mut kept: Vec<T> = Vec::with_capacity(points.len());
    for p in points.drain(..) {
        match kept.last_mut() {
            Some(last) if key(last) == key(&p) => *last = p,
            _ => kept.push(p),
        }
    }
    *points = kept;
}

/// Parses the text of a metrics log; `path` only names the file in errors.
pub fn parse_metrics(text: &str, path: &Path) -> Result<Metrics, VizError> {
    let err = |line: usize, reason: String| VizError::Metrics {
        path: path.to_path_buf(),
        line,
        reason,
    };
    let mut out = Metrics::default();
    let lines = text.lines().count();
    for (i, raw) in text.lines().enumerate() {
        let line = i + 1;
        if raw.trim().is_empty() {
            continue;
        }
        let value: serde_json::Value = match serde_json::from_str(raw) {
            Ok(v) => v,
            // A run killed while appending leaves its last line without the newline: that
            // line is lost, the log before it is whole.
            Err(_) if line == lines && !text.ends_with('\n') => {
                out.torn_last_line = true;
                continue;
            }
            Err(e) => return Err(err(line, format!("not JSON: {e}"))),
        };
        let phase = value
            .get("phase")
            .ok_or_else(|| err(line, "no \"phase\" field".into()))?
            .as_str()
            .ok_or_else(|| err(line, "\"phase\" is not a string".into()))?
            .to_string();
        match phase.as_str() {
            "imitation" => out.imitation.push(
                ImitationPoint::deserialize(&value)
                    .map_err(|e| err(line, format!("bad imitation line: {e}")))?,
            ),
            "rl" => out.rl.push(
                RlPoint::deserialize(&value).map_err(|e| err(line, format!("bad rl line: {e}")))?,
            ),
            "validation" => out.validation.push(
                ValidationPoint::deserialize(&value)
                    .map_err(|e| err(line, format!("bad validation line: {e}")))?,
            ),
            _ => {}
        }
    }
    last_per_key(&mut out.imitation, |p| p.epoch.into());
    last_per_key(&mut out.rl, |p| p.episode);
    last_per_key(&mut out.validation, |p| p.episode);
    Ok(out)
}

/// Reads and parses `path`.
pub fn read_metrics(path: &Path) -> Result<Metrics, VizError> {
    let text = std::fs::read_to_string(path).map_err(|source| VizError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    parse_metrics(&text, path)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_both_phases_and_skips_others() {
        let text = r#"{"phase":"imitation","epoch":0,"loss":0.5,"wall_s":1.0}

{"phase":"rl","episode":0,"epsilon":0.5,"outcome":"success","steps":40,"return_sum":0.8,"loss":null,"success_rate_window":1.0,"collision_rate_window":0.0,"timeout_rate_window":0.0,"policy_version":1,"env_steps":40,"replay_size":100,"wall_s":2.0}
{"phase":"eval","whatever":1}
"#;
        let m = parse_metrics(text, Path::new("m.jsonl")).unwrap();
        assert_eq!(m.imitation.len(), 1);
        assert_eq!(m.rl.len(), 1);
        assert_eq!(m.rl[0].loss, None);
        assert_eq!(m.rl[0].steps, 40);
        assert!(m.validation.is_empty());
    }

    /// A validation line as `fsrl train` writes it.
    fn validation(episode: u64, success: f64, wall_s: f64) -> String {
        format!(
            r#"{{"phase":"validation","episode":{episode},"env_steps":{},"policy_version":{},"episodes":100,"seed_start":0,"success_rate":{success},"collision_rate":{},"timeout_rate":0.0,"discomfort":0.12,"nav_time_s":null,"mean_return":0.25,"wall_s":{wall_s}}}"#,
            40 * episode,
            10 + episode,
            1.0 - success
        )
    }

    fn rl(episode: u64, wall_s: f64) -> String {
        format!(
            r#"{{"phase":"rl","episode":{episode},"epsilon":0.5,"outcome":"success","steps":40,"return_sum":0.8,"loss":0.01,"success_rate_window":1.0,"collision_rate_window":0.0,"timeout_rate_window":0.0,"wall_s":{wall_s}}}"#
        )
    }

    fn parse_lines(lines: &[String]) -> Metrics {
        parse_metrics(&lines.join("\n"), Path::new("m.jsonl")).unwrap()
    }

    #[test]
    fn validation_lines_are_read() {
        let m = parse_lines(&[
            validation(0, 0.25, 3.0),
            rl(0, 4.0),
            rl(1, 5.0),
            validation(2, 0.5, 9.5),
        ]);
        assert_eq!(m.rl.len(), 2);
        assert_eq!(m.validation.len(), 2);
        let v = &m.validation[1];
        assert_eq!((v.episode, v.success_rate, v.collision_rate), (2, 0.5, 0.5));
        assert_eq!((v.discomfort, v.nav_time_s, v.wall_s), (0.12, None, 9.5));
        assert_eq!((v.episodes, v.env_steps, v.policy_version), (100, 80, 12));
        assert_eq!(v.mean_return, Some(0.25));

        let e = parse_metrics(
            r#"{"phase":"validation","episode":5,"success_rate":1.0}"#,
            Path::new("m.jsonl"),
        )
        .unwrap_err();
        assert!(
            e.to_string().starts_with("m.jsonl:1: bad validation line"),
            "{e}"
        );
    }

    #[test]
    fn a_resumed_run_keeps_the_last_line_of_each_episode() {
        // Checkpoint after episode 1; the run went on to episode 3, then resumed from 2.
        let m = parse_lines(&[
            validation(0, 0.1, 1.0),
            rl(0, 2.0),
            rl(1, 3.0),
            validation(2, 0.2, 4.0),
            rl(2, 5.0),
            rl(3, 6.0),
            validation(4, 0.3, 7.0),
            // resumed
            rl(2, 8.0),
            validation(4, 0.4, 9.0),
            rl(3, 10.0),
            validation(4, 0.5, 11.0),
        ]);
        let rl: Vec<(u64, f64)> = m.rl.iter().map(|p| (p.episode, p.wall_s)).collect();
        assert_eq!(rl, [(0, 2.0), (1, 3.0), (2, 8.0), (3, 10.0)]);
        let v: Vec<(u64, f64)> = m
            .validation
            .iter()
            .map(|p| (p.episode, p.success_rate))
            .collect();
        assert_eq!(v, [(0, 0.1), (2, 0.2), (4, 0.5)]);
    }

    #[test]
    fn malformed_lines_name_file_and_line() {
        let text = "{\"phase\":\"imitation\",\"epoch\":0,\"loss\":0.5}\n{not json\n";
        let e = parse_metrics(text, Path::new("run/metrics.jsonl")).unwrap_err();
        assert!(
            e.to_string().starts_with("run/metrics.jsonl:2: not JSON"),
            "{e}"
        );
        let text = "{\"phase\":\"rl\",\"episode\":3}\n";
        let e = parse_metrics(text, Path::new("m.jsonl")).unwrap_err();
        assert!(e.to_string().starts_with("m.jsonl:1: bad rl line"), "{e}");
        let e = parse_metrics("{\"epoch\":1}", Path::new("m.jsonl")).unwrap_err();
        assert!(e.to_string().contains("no \"phase\""), "{e}");
    }

    #[test]
    fn a_last_line_cut_by_a_crash_is_left_out_and_flagged() {
        let whole = "{\"phase\":\"imitation\",\"epoch\":0,\"loss\":0.5}\n";
        let m = parse_metrics(whole, Path::new("m.jsonl")).unwrap();
        assert!(!m.torn_last_line);
        let torn = format!("{whole}{{\"phase\":\"rl\",\"epis");
        let m = parse_metrics(&torn, Path::new("m.jsonl")).unwrap();
        assert!(m.torn_last_line && m.imitation.len() == 1 && m.rl.is_empty());
        // Ended by a newline, the same line was written whole: malformed, not torn.
        let e = parse_metrics(&format!("{torn}\n"), Path::new("m.jsonl")).unwrap_err();
        assert!(e.to_string().starts_with("m.jsonl:2: not JSON"), "{e}");
    }
}
