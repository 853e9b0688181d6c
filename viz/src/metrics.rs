//! Reading a run's `metrics.jsonl` (one JSON object per line, written by `fsrl train`): phase
//! `"imitation"` lines `{epoch, loss, wall_s}` and phase `"rl"` lines `{episode, epsilon, outcome,
//! steps, return_sum, loss, success_rate_window, ...}`. Lines of other phases are skipped (newer
//! writers may add some); blank lines are ignored; anything else malformed is an error naming the
//! file and the line.

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

/// A whole metrics log.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Metrics {
    pub imitation: Vec<ImitationPoint>,
    pub rl: Vec<RlPoint>,
}

/// Parses the text of a metrics log; `path` only names the file in errors.
pub fn parse_metrics(text: &str, path: &Path) -> Result<Metrics, VizError> {
    let err = |line: usize, reason: String| VizError::Metrics {
        path: path.to_path_buf(),
        line,
        reason,
    };
    let mut out = Metrics::default();
    for (i, raw) in text.lines().enumerate() {
        let line = i + 1;
        if raw.trim().is_empty() {
            continue;
        }
        let value: serde_json::Value =
            serde_json::from_str(raw).map_err(|e| err(line, format!("not JSON: {e}")))?;
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
            _ => {}
        }
    }
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
}
