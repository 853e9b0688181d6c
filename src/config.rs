//! The run configuration file (TOML): one typed struct, unknown keys rejected, every value
//! defaulted, validated once at start-up with every problem reported together.

use std::path::Path;

use anyhow::Context;
use policy::method::{Method, TrainConfig};
use serde::{Deserialize, Serialize};
use sim::{ConfigError, Setting, SimConfig};

/// What one training run is.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RunSection {
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
            method: "fsrl".into(),
            setting: "env1-invisible".into(),
            seed: 0,
        }
    }
}

/// The whole file. Each table belongs to one part of the system.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FileConfig {
    pub run: RunSection,
    /// The simulator (SPEC §2–3).
    pub sim: SimConfig,
    /// The training schedule (SPEC §5).
    pub train: TrainConfig,
}

/// A validated run configuration.
#[derive(Debug, Clone)]
pub struct Resolved {
    pub method: Method,
    pub setting: Setting,
    pub file: FileConfig,
}

impl FileConfig {
    /// Reads and parses `path`; a missing path means all defaults.
    pub fn load(path: Option<&Path>) -> anyhow::Result<Self> {
        let Some(path) = path else {
            return Ok(Self::default());
        };
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read config file {}", path.display()))?;
        toml::from_str(&text).with_context(|| format!("invalid config file {}", path.display()))
    }

    /// Validates everything at once.
    pub fn resolve(self, extra_problems: Vec<String>) -> Result<Resolved, ConfigError> {
        let mut problems = extra_problems;
        let method = match self.run.method.parse::<Method>() {
            Ok(m) => Some(m),
            Err(e) => {
                problems.push(e.to_string());
                None
            }
        };
        let setting = match self.sim.resolve_settings(&[self.run.setting.as_str()]) {
            Ok(s) => Some(s[0]),
            Err(e) => {
                problems.extend(e.problems);
                None
            }
        };
        problems.extend(self.train.problems());
        if self.sim.humans.count == 0 && method.is_some_and(|m| m.net().is_some()) {
            problems.push("sim.humans.count must be at least 1 for a learned policy".into());
        }
        match (method, setting) {
            (Some(method), Some(setting)) if problems.is_empty() => Ok(Resolved {
                method,
                setting,
                file: self,
            }),
            _ => Err(ConfigError { problems }),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unknown_keys_are_rejected_with_their_name() {
        let err = toml::from_str::<FileConfig>("[sim]\ndt = 0.1\n").unwrap_err();
        assert!(err.to_string().contains("unknown field `dt`"), "{err}");
        let err = toml::from_str::<FileConfig>("[sim.robot]\nradius_m = \"big\"\n").unwrap_err();
        assert!(err.to_string().contains("radius_m"), "{err}");
        let err = toml::from_str::<FileConfig>("[train.rl]\nepisodes = 5\nlr = 0.1\n").unwrap_err();
        assert!(err.to_string().contains("unknown field `lr`"), "{err}");
    }

    #[test]
    fn partial_tables_keep_the_other_defaults() {
        let c: FileConfig = toml::from_str(
            "[sim]\ndt_s = 0.1\n[sim.humans]\ncount = 5\n[train.rl]\nepisodes = 7\n",
        )
        .unwrap();
        assert_eq!(c.sim.dt_s, 0.1);
        assert_eq!(c.sim.humans.count, 5);
        assert_eq!(c.sim.humans.radius_m, 0.3);
        assert_eq!(c.train.rl.episodes, 7);
        assert_eq!(c.train.rl.batch_size, 100);
    }

    #[test]
    fn the_resolved_config_round_trips_through_toml() {
        let c = FileConfig::default();
        let text = toml::to_string(&c).unwrap();
        let back: FileConfig = toml::from_str(&text).unwrap();
        assert_eq!(back, c);
    }

    #[test]
    fn every_problem_of_a_run_is_reported() {
        let mut c = FileConfig::default();
        c.run.method = "dqn".into();
        c.run.setting = "env4-visible".into();
        c.train.gamma = 2.0;
        c.sim.dt_s = 0.0;
        let err = c
            .resolve(vec!["--rl-episodes must be at least 1".into()])
            .unwrap_err();
        assert_eq!(err.problems.len(), 5, "{err}");
    }
}
