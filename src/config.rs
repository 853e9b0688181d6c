//! The run configuration file (TOML): one typed struct, unknown keys rejected, every value
//! defaulted, validated once at start-up.

use std::path::Path;

use anyhow::Context;
use serde::Deserialize;
use sim::SimConfig;

/// The whole file. Each table belongs to one part of the system.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FileConfig {
    /// The simulator (SPEC §2–3).
    pub sim: SimConfig,
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
    }

    #[test]
    fn partial_tables_keep_the_other_defaults() {
        let c: FileConfig = toml::from_str("[sim]\ndt_s = 0.1\n[sim.humans]\ncount = 5\n").unwrap();
        assert_eq!(c.sim.dt_s, 0.1);
        assert_eq!(c.sim.humans.count, 5);
        assert_eq!(c.sim.humans.radius_m, 0.3);
        assert_eq!(c.sim.time_limit_s, 25.0);
    }
}
