//! The command-line options that override a run's config file; the file itself is
//! `launch::config` (re-exported here).

pub use launch::config::{run_checkpoint, FileConfig, Resolved};

/// The command-line options that override a run's config file, shared by `fsrl train` and the
/// role processes.
#[derive(Debug, Clone, Default, clap::Args)]
pub struct RunOverrides {
    /// Run configuration (TOML: [run], [sim], [train], [transport], [learner], [actor], [evaluator])
    #[arg(long)]
    pub config: Option<std::path::PathBuf>,
    /// orca, lstm-rl, sarl, fsrl, sarl+foresight, sarl+efficiency [default: fsrl]
    #[arg(long)]
    pub method: Option<String>,
    /// One of the six settings [default: env1-invisible]
    #[arg(long)]
    pub setting: Option<String>,
    /// Run seed [default: 0]
    #[arg(long)]
    pub seed: Option<u64>,
    /// Demonstration episodes for imitation learning [default: 1000; paper: 3000]
    #[arg(long)]
    pub il_episodes: Option<u64>,
    /// Imitation epochs [default: 30; paper: 50]
    #[arg(long)]
    pub il_epochs: Option<u32>,
    /// RL episodes [default: 5000; paper: 10000]
    #[arg(long)]
    pub rl_episodes: Option<u64>,
}

impl RunOverrides {
    /// Loads the config file and applies the overrides (not yet validated).
    pub fn load(&self) -> anyhow::Result<FileConfig> {
        let mut f = FileConfig::load(self.config.as_deref())?;
        if let Some(v) = &self.method {
            f.run.method = v.clone();
        }
        if let Some(v) = &self.setting {
            f.run.setting = v.clone();
        }
        if let Some(v) = self.seed {
            f.run.seed = v;
        }
        if let Some(v) = self.il_episodes {
            f.train.imitation.episodes = v;
        }
        if let Some(v) = self.il_epochs {
            f.train.imitation.epochs = v;
        }
        if let Some(v) = self.rl_episodes {
            f.train.rl.episodes = v;
        }
        Ok(f)
    }
}
