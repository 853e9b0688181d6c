//! A run directory's configuration as the analysis reads it: `[run]`, `[sim]` and `[train]` of
//! its `config.toml` (the file `fsrl train` writes), and the name of a run's directory. The
//! transport and process tables belong to the processes (the CLI's `FileConfig`) and are not read
//! here, so a report can be made of a run from a machine with another cluster. Also the run's
//! `run.json` ([`RunTiming`]: the mode that trained it and where the time went) and the
//! "How the run went" section of a distributed run's report ([`distributed_summary`]).

use std::path::Path;

use anyhow::Context;
use policy::method::{Method, TrainConfig};
use serde::{Deserialize, Serialize};
use sim::{Setting, SimConfig};

/// `<method>-<setting>-s<seed>`, `+` written as `-` (`sarl-foresight-env1-invisible-s0`): the
/// name of a run's directory (`fsrl train`, `fsrl reproduce`).
pub fn run_name(method: Method, setting: Setting, seed: u64) -> String {
    format!("{}-{setting}-s{seed}", method.name().replace('+', "-"))
}

/// What one training run is.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RunSection {
    /// Run id: the first key chunk after `fsrl/` (letters, digits, `-`, `_`).
    pub id: String,
    /// orca, lstm-rl, sarl, fsrl, sarl+foresight, sarl+efficiency
    pub method: String,
    /// One of the six settings, e.g. env1-invisible.
    pub setting: String,
    /// Run seed: network initialisation and every episode seed derive from it.
    pub seed: u64,
}

impl Default for RunSection {
    fn default() -> Self {
        Self {
            id: "local".into(),
            method: "fsrl".into(),
            setting: "env1-invisible".into(),
            seed: 0,
        }
    }
}

/// The parts of a run's `config.toml` the analysis needs. Unknown tables are allowed (they
/// belong to the processes); inside `[run]`, `[sim]` and `[train]` unknown keys are refused as
/// everywhere.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct RunFile {
    pub run: RunSection,
    pub sim: SimConfig,
    pub train: TrainConfig,
}

impl RunFile {
    /// Reads and parses a run's config file.
    pub fn load(path: &Path) -> anyhow::Result<Self> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read config file {}", path.display()))?;
        toml::from_str(&text).with_context(|| format!("invalid config file {}", path.display()))
    }
}

/// `run.json` of a run directory: which mode trained it and where its wall-clock time went
/// (seconds; in a distributed run also each process's waiting and the realised replay ratio).
pub struct RunTiming {
    value: serde_json::Map<String, serde_json::Value>,
}

impl RunTiming {
    pub fn new(mode: &str) -> Self {
        let mut value = serde_json::Map::new();
        value.insert("mode".into(), mode.into());
        Self { value }
    }
    pub fn set(&mut self, key: &str, v: impl Into<serde_json::Value>) {
        self.value.insert(key.into(), v.into());
    }
    /// Adds `key` to the recorded time (a resumed run adds its invocation's share).
    pub fn add_s(&mut self, key: &str, seconds: f64) {
        let before = self.value.get(key).and_then(|v| v.as_f64()).unwrap_or(0.0);
        self.set(key, before + seconds);
    }
    /// What an earlier invocation of the same run recorded (a resumed run goes on from it).
    pub fn read(out: &Path, mode: &str) -> Self {
        let mut t = Self::new(mode);
        if let Ok(text) = std::fs::read_to_string(out.join("run.json")) {
            if let Ok(serde_json::Value::Object(m)) = serde_json::from_str(&text) {
                if m.get("mode").and_then(|v| v.as_str()) == Some(mode) {
                    t.value = m;
                }
            }
        }
        t
    }
    pub fn write(&self, out: &Path) -> anyhow::Result<()> {
        let path = out.join("run.json");
        std::fs::write(&path, serde_json::to_string_pretty(&self.value)? + "\n")
            .with_context(|| format!("cannot write {}", path.display()))
    }
}
/// Where a distributed run's time went, from each process's last metrics: the realised replay
/// ratio and policy lag, and how long each process waited; recorded into `timing` and returned
/// as a Markdown section of the run's report. A run whose learner hardly waited was
/// learner-bound (more actors would not have made it faster); one whose actors hardly waited
/// was actor-bound.
pub fn distributed_summary(
    last: &std::collections::BTreeMap<String, proto::Metrics>,
    timing: &mut RunTiming,
) -> String {
    let of = |role: &'static str| {
        last.iter()
            .filter(move |(k, _)| k.starts_with(role))
            .map(|(_, m)| m)
    };
    let val = |m: &proto::Metrics, k: &str| m.values.get(k).copied().unwrap_or(0.0);
    let mut s = String::from("\n## How the run went (distributed)\n\n");
    if let Some(l) = of("learner").next() {
        let wall = l.wall_time_s.max(1e-9);
        for k in [
            "updates_per_episode",
            "policy_lag_mean",
            "policy_lag_p95",
            "policy_lag_max",
            "wait_s",
            "train_s",
        ] {
            timing.set(&format!("learner_{k}"), val(l, k));
        }
        s += &format!(
            "- learner: {:.1} updates per accepted episode, policy lag mean {:.2} (p95 {}), waited {:.0} s for episodes and trained {:.0} s of {:.0} s ({:.0} % waiting)\n",
            val(l, "updates_per_episode"),
            val(l, "policy_lag_mean"),
            val(l, "policy_lag_p95"),
            val(l, "wait_s"),
            val(l, "train_s"),
            wall,
            100.0 * val(l, "wait_s") / wall
        );
    }
    let actors: Vec<&proto::Metrics> = of("actor").collect();
    if !actors.is_empty() {
        let wait: f64 = actors.iter().map(|m| val(m, "wait_s")).sum();
        let sim: f64 = actors.iter().map(|m| val(m, "sim_s")).sum();
        let wall: f64 = actors.iter().map(|m| m.wall_time_s).sum::<f64>().max(1e-9);
        timing.set("actors_wait_s", wait);
        timing.set("actors_sim_s", sim);
        s += &format!(
            "- {} actor(s): simulated {sim:.0} s and waited {wait:.0} s in all ({:.0} % waiting)\n",
            actors.len(),
            100.0 * wait / wall
        );
    }
    if let Some(e) = of("evaluator").next() {
        timing.set("validation_s", val(e, "busy_s"));
        timing.set("evaluator_wait_s", val(e, "wait_s"));
        s += &format!(
            "- evaluator: {} validations in {:.0} s, waited {:.0} s\n",
            val(e, "validations"),
            val(e, "busy_s"),
            val(e, "wait_s")
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_run_file_reads_its_own_tables_and_leaves_the_others() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("config.toml");
        std::fs::write(
            &path,
            "[run]\nmethod = \"sarl\"\nseed = 3\n[train.rl]\nepsilon_decay_episodes = 7\n\
             [transport.zenoh]\nanything = 1\n[learner]\nthreads = 2\n",
        )
        .unwrap();
        let f = RunFile::load(&path).unwrap();
        assert_eq!((f.run.method.as_str(), f.run.seed), ("sarl", 3));
        assert_eq!(f.train.rl.epsilon_decay_episodes, 7);
        assert_eq!(f.run.setting, "env1-invisible");

        std::fs::write(&path, "[run]\nmethd = \"sarl\"\n").unwrap();
        let e = format!("{:#}", RunFile::load(&path).unwrap_err());
        assert!(e.contains("methd"), "{e}");
    }

    #[test]
    fn run_names_write_plus_as_dash() {
        let s: Setting = "env3-visible".parse().unwrap();
        assert_eq!(
            run_name(Method::SarlForesight, s, 2),
            "sarl-foresight-env3-visible-s2"
        );
    }
}
