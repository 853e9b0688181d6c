//! The command-line options that override a run's config file; the file itself is
//! `launch::config` (re-exported here).

pub use launch::config::{FileConfig, Resolved};

/// The command-line options that override a run's config file, shared by `fsrl train` and the
/// role processes.
#[derive(Debug, Clone, Default, clap::Args)]
pub struct RunOverrides {
    /// Run configuration (TOML: [run], [sim], [train], [transport], [learner], [actor], [evaluator])
    #[arg(long)]
    pub config: Option<std::path::PathBuf>,
    /// orca, lstm-rl, sarl, fsrl, sarl+foresight, sarl+efficiency, or fsrl-plan (beyond the
    /// paper: FSRL deciding by depth-2 planning) [default: fsrl]
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

/// `--replay-ratio` of `fsrl train` and `fsrl reproduce`, parsed once (by clap): `MIN,MAX`,
/// the adaptive mode's bounds, or `fixed` (`None`: `train.rl.batches_per_episode` updates per
/// episode).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReplayRatioArg(pub Option<policy::method::ReplayRatio>);

impl ReplayRatioArg {
    /// clap's value parser: the syntax, and the bounds as [`policy::method::TrainConfig::problems`]
    /// checks them (how they go with the rest of the run's `[train]` is checked with the
    /// resolved config, before anything is written or started).
    pub fn parse(s: &str) -> Result<Self, String> {
        let ratio = policy::method::ReplayRatio::parse_arg(s)?;
        if let Some(r) = ratio {
            let mut alone = policy::method::TrainConfig::default();
            alone.rl.replay_ratio = Some(r);
            if let Some(p) = alone.problems().into_iter().next() {
                return Err(p);
            }
        }
        Ok(Self(ratio))
    }
}

/// How a monitor (`fsrl watch`, `fsrl dashboard`) reaches a run: the flags both take, and the
/// transport config they make (role Monitor, this process's id).
#[derive(Debug, clap::Args)]
pub struct MonitorArgs {
    /// zenoh endpoint of a process of the run (the learner) or a router (repeatable)
    #[arg(long, required_unless_present = "config")]
    pub connect: Vec<String>,
    /// Take the zenoh session (mode, endpoints, TLS, credentials) from this run config's
    /// [transport.zenoh], e.g. deploy/cluster-monitor.toml; --connect still overrides
    #[arg(long)]
    pub config: Option<std::path::PathBuf>,
}

impl MonitorArgs {
    /// The monitor's transport config for run `run` (`--run`): the file's `[transport.zenoh]`
    /// (with `--connect` over its endpoints) or a peer connecting to `--connect`.
    pub fn transport_config(&self, run: &str) -> anyhow::Result<transport::TransportConfig> {
        use proto::{Role, RunId, SenderId};
        let run = RunId::new(run).map_err(|e| anyhow::anyhow!("--run `{run}`: {e}"))?;
        let mut cfg =
            transport::TransportConfig::new(run, SenderId::new(Role::Monitor, std::process::id()));
        cfg.zenoh = match &self.config {
            Some(path) => {
                let mut z = FileConfig::load(Some(path))?.transport.zenoh;
                if !self.connect.is_empty() {
                    z.connect = self.connect.clone();
                }
                z
            }
            None => {
                transport::ZenohConfig::peer(vec!["tcp/127.0.0.1:0".into()], self.connect.clone())
            }
        };
        Ok(cfg)
    }
}
