//! Self-describing checkpoints: method, network description, online and target weights, Adam
//! state, counters, the sampling generator, the resolved configs, and the replay memory. They
//! load back bit-exact; a truncated, corrupt or mismatched file is a clear error, never a panic.
//!
//! File layout (`frame.rs`): `b"FSRLCKPT"`, format version (u32 LE), payload length
//! (u64 LE), payload (MessagePack, field names included), CRC-32 of the payload (u32 LE). Files
//! are written to a temporary name (`<name>.tmp`), synced, renamed, and the directory is synced
//! (`frame.rs`): when [`save`] returns `Ok` the checkpoint survives a power loss, and a
//! crash at any point leaves the previous checkpoint whole. A failed write (a full disk)
//! removes the temporary file.
//!
//! A learner resumes a checkpoint only if it is of the same run: [`Loaded::check_identity`]
//! compares run id, method, setting and seed with the configuration.

use std::path::{Path, PathBuf};

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use policy::config::{LstmRlConfig, NetConfig, SarlConfig};
use policy::method::{Method, TrainConfig};
use policy::optim::{Adam, AdamConfig};
use policy::train::Trainer;
use policy::ValueNet;
use sim::SimConfig;

use crate::core::{Counters, LearnerCore};
use crate::frame::{self, FrameError, Probe};
use crate::replay::{Columns, Replay};

pub(crate) const MAGIC: &[u8; 8] = b"FSRLCKPT";
/// Bumped whenever the payload changes incompatibly.
pub const FORMAT_VERSION: u32 = 1;

/// Why a checkpoint could not be written or read.
#[derive(Debug, thiserror::Error)]
pub enum CheckpointError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{0}: not an fsrl checkpoint (bad magic bytes)")]
    NotACheckpoint(PathBuf),
    #[error("{path}: checkpoint format version {found}, this build reads version {expected}")]
    Version {
        path: PathBuf,
        found: u32,
        expected: u32,
    },
    #[error("{path}: truncated checkpoint ({got} bytes, expected {expected})")]
    Truncated {
        path: PathBuf,
        got: u64,
        expected: u64,
    },
    #[error("{0}: corrupt checkpoint (checksum mismatch)")]
    Corrupt(PathBuf),
    #[error("{path}: cannot decode checkpoint: {reason}")]
    Decode { path: PathBuf, reason: String },
    #[error("{path}: inconsistent checkpoint: {reason}")]
    Mismatch { path: PathBuf, reason: String },
    #[error("{path}: checkpoint of another run ({differences}); refusing to resume it")]
    OtherRun { path: PathBuf, differences: String },
}

/// What a run is, besides the learner's state.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunInfo {
    pub run_id: String,
    pub setting: String,
    pub run_seed: u64,
    /// Per actor, every episode index below this one has been accepted (distributed runs).
    #[serde(default)]
    pub accepted_below: std::collections::BTreeMap<u32, u64>,
}

/// A loaded checkpoint.
pub struct Loaded {
    pub core: LearnerCore,
    pub sim: SimConfig,
    pub run: RunInfo,
}

/// What a learner is configured to run; a checkpoint it resumes must be of the same run.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RunIdentity {
    pub run_id: String,
    pub method: Method,
    pub setting: String,
    pub run_seed: u64,
}

impl Loaded {
    /// `Ok` if this checkpoint (read from `path`) is of the run `expected`; otherwise an error
    /// naming every field that differs, with both values.
    pub fn check_identity(
        &self,
        path: &Path,
        expected: &RunIdentity,
    ) -> Result<(), CheckpointError> {
        let mut differences = Vec::new();
        let mut differ = |what: &str, found: String, wanted: String| {
            if found != wanted {
                differences.push(format!(
                    "{what} `{found}` in the checkpoint, `{wanted}` configured"
                ));
            }
        };
        differ("run id", self.run.run_id.clone(), expected.run_id.clone());
        differ(
            "method",
            self.core.method().name().into(),
            expected.method.name().into(),
        );
        differ(
            "setting",
            self.run.setting.clone(),
            expected.setting.clone(),
        );
        differ(
            "seed",
            self.run.run_seed.to_string(),
            expected.run_seed.to_string(),
        );
        if differences.is_empty() {
            Ok(())
        } else {
            Err(CheckpointError::OtherRun {
                path: path.to_path_buf(),
                differences: differences.join("; "),
            })
        }
    }
}

/// Where [`save`] writes before renaming to `path`.
pub(crate) fn tmp_path(path: &Path) -> PathBuf {
    path.with_extension("tmp")
}

/// A network's description as checkpoints and model files write it.
#[derive(Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case")]
pub(crate) enum NetDesc {
    Sarl {
        mlp1: Vec<usize>,
        mlp2: Vec<usize>,
        attention: Vec<usize>,
        mlp3: Vec<usize>,
    },
    LstmRl {
        hidden: usize,
        mlp: Vec<usize>,
    },
}

impl From<&NetConfig> for NetDesc {
    fn from(c: &NetConfig) -> Self {
        match c {
            NetConfig::Sarl(s) => NetDesc::Sarl {
                mlp1: s.mlp1_dims.clone(),
                mlp2: s.mlp2_dims.clone(),
                attention: s.attention_dims.clone(),
                mlp3: s.mlp3_dims.clone(),
            },
            NetConfig::LstmRl(l) => NetDesc::LstmRl {
                hidden: l.hidden_dim,
                mlp: l.mlp_dims.clone(),
            },
        }
    }
}

impl From<NetDesc> for NetConfig {
    fn from(d: NetDesc) -> Self {
        match d {
            NetDesc::Sarl {
                mlp1,
                mlp2,
                attention,
                mlp3,
            } => NetConfig::Sarl(SarlConfig {
                mlp1_dims: mlp1,
                mlp2_dims: mlp2,
                attention_dims: attention,
                mlp3_dims: mlp3,
            }),
            NetDesc::LstmRl { hidden, mlp } => NetConfig::LstmRl(LstmRlConfig {
                hidden_dim: hidden,
                mlp_dims: mlp,
            }),
        }
    }
}

pub(crate) fn to_bytes(v: &[f32]) -> Vec<u8> {
    let mut out = Vec::with_capacity(v.len() * 4);
    for x in v {
        out.extend_from_slice(&x.to_le_bytes());
    }
    out
}

pub(crate) fn from_bytes(b: &[u8], what: &str) -> Result<Vec<f32>, String> {
    if !b.len().is_multiple_of(4) {
        return Err(format!(
            "{what}: {} bytes is not a whole number of f32",
            b.len()
        ));
    }
    Ok(b.chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect())
}

#[derive(Serialize, Deserialize)]
struct AdamRec {
    lr: f32,
    beta1: f32,
    beta2: f32,
    eps: f32,
    step: u64,
    #[serde(with = "serde_bytes")]
    m: Vec<u8>,
    #[serde(with = "serde_bytes")]
    v: Vec<u8>,
}

#[derive(Serialize, Deserialize)]
pub(crate) struct CountersRec {
    demo_episodes: u64,
    imitation_done: bool,
    rl_episodes: u64,
    updates: u64,
    env_steps: u64,
    policy_version: u64,
}

impl From<Counters> for CountersRec {
    fn from(c: Counters) -> Self {
        Self {
            demo_episodes: c.demo_episodes,
            imitation_done: c.imitation_done,
            rl_episodes: c.rl_episodes,
            updates: c.updates,
            env_steps: c.env_steps,
            policy_version: c.policy_version,
        }
    }
}

impl From<CountersRec> for Counters {
    fn from(c: CountersRec) -> Self {
        Self {
            demo_episodes: c.demo_episodes,
            imitation_done: c.imitation_done,
            rl_episodes: c.rl_episodes,
            updates: c.updates,
            env_steps: c.env_steps,
            policy_version: c.policy_version,
        }
    }
}

#[derive(Serialize, Deserialize)]
struct RngRec {
    seed: [u8; 32],
    stream: u64,
    word_pos_hi: u64,
    word_pos_lo: u64,
}

#[derive(Serialize, Deserialize)]
struct ReplayRec {
    capacity: usize,
    humans: usize,
    next: usize,
    #[serde(with = "serde_bytes")]
    states: Vec<u8>,
    #[serde(with = "serde_bytes")]
    next_states: Vec<u8>,
    #[serde(with = "serde_bytes")]
    rewards: Vec<u8>,
    #[serde(with = "serde_bytes")]
    discounts: Vec<u8>,
    #[serde(with = "serde_bytes")]
    returns: Vec<u8>,
}

#[derive(Serialize, Deserialize)]
struct Payload {
    run: RunInfo,
    method: Method,
    net: NetDesc,
    #[serde(with = "serde_bytes")]
    online: Vec<u8>,
    #[serde(with = "serde_bytes")]
    target: Vec<u8>,
    adam: AdamRec,
    counters: CountersRec,
    rng: RngRec,
    train: TrainConfig,
    sim: SimConfig,
    replay: ReplayRec,
}

/// Writes the whole learner state to `path`, atomically and durably (module docs).
pub fn save(
    path: &Path,
    core: &LearnerCore,
    sim: &SimConfig,
    run: &RunInfo,
) -> Result<(), CheckpointError> {
    save_with(path, core, sim, run, &Probe::none())
}

/// [`save`], reporting every file-system step to `probe`.
pub fn save_with(
    path: &Path,
    core: &LearnerCore,
    sim: &SimConfig,
    run: &RunInfo,
    probe: &Probe,
) -> Result<(), CheckpointError> {
    let t = core.trainer();
    let adam = t.adam();
    let cfg = adam.config();
    let c = core.counters();
    let rng = core.rng();
    let word_pos = rng.get_word_pos();
    let cols = core.replay().columns();
    let payload = Payload {
        run: run.clone(),
        method: core.method(),
        net: NetDesc::from(t.online().config()),
        online: to_bytes(t.online().params()),
        target: to_bytes(t.target().params()),
        adam: AdamRec {
            lr: cfg.lr,
            beta1: cfg.beta1,
            beta2: cfg.beta2,
            eps: cfg.eps,
            step: adam.step_count(),
            m: to_bytes(adam.m()),
            v: to_bytes(adam.v()),
        },
        counters: c.into(),
        rng: RngRec {
            seed: rng.get_seed(),
            stream: rng.get_stream(),
            word_pos_hi: (word_pos >> 64) as u64,
            word_pos_lo: word_pos as u64,
        },
        train: core.config().clone(),
        sim: sim.clone(),
        replay: ReplayRec {
            capacity: core.replay().capacity(),
            humans: core.replay().humans(),
            next: cols.next,
            states: to_bytes(cols.states),
            next_states: to_bytes(cols.next_states),
            rewards: to_bytes(cols.rewards),
            discounts: to_bytes(cols.discounts),
            returns: to_bytes(cols.returns),
        },
    };
    let body = rmp_serde::to_vec_named(&payload).map_err(|e| CheckpointError::Decode {
        path: path.to_path_buf(),
        reason: e.to_string(),
    })?;
    frame::write_atomic(path, &tmp_path(path), MAGIC, FORMAT_VERSION, &body, probe)
        .map_err(|(path, source)| CheckpointError::Io { path, source })
}

/// Reads a checkpoint written by [`save`].
pub fn load(path: &Path) -> Result<Loaded, CheckpointError> {
    let bytes = std::fs::read(path).map_err(|source| CheckpointError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    decode(path, &bytes)
}

/// [`load`] of a file's bytes already read (`path` names them in errors).
pub(crate) fn decode(path: &Path, bytes: &[u8]) -> Result<Loaded, CheckpointError> {
    let p = || path.to_path_buf();
    let body = frame::open(bytes, MAGIC, FORMAT_VERSION).map_err(|e| match e {
        FrameError::BadMagic => CheckpointError::NotACheckpoint(p()),
        FrameError::Version(found) => CheckpointError::Version {
            path: p(),
            found,
            expected: FORMAT_VERSION,
        },
        FrameError::Truncated { got, expected } => CheckpointError::Truncated {
            path: p(),
            got,
            expected,
        },
        FrameError::Corrupt => CheckpointError::Corrupt(p()),
    })?;
    let payload: Payload = rmp_serde::from_slice(body).map_err(|e| CheckpointError::Decode {
        path: p(),
        reason: e.to_string(),
    })?;
    rebuild(payload).map_err(|reason| CheckpointError::Mismatch { path: p(), reason })
}

fn rebuild(pl: Payload) -> Result<Loaded, String> {
    let net_cfg = NetConfig::from(pl.net);
    if pl.method.net().map(|n| n.kind()) != Some(net_cfg.kind()) {
        return Err(format!(
            "method {} does not use a {} network",
            pl.method,
            net_cfg.kind().name()
        ));
    }
    let online = ValueNet::from_params(net_cfg.clone(), from_bytes(&pl.online, "online weights")?)
        .map_err(|e| format!("online weights: {e}"))?;
    let target = ValueNet::from_params(net_cfg, from_bytes(&pl.target, "target weights")?)
        .map_err(|e| format!("target weights: {e}"))?;
    let a = pl.adam;
    let adam = Adam::from_state(
        AdamConfig {
            lr: a.lr,
            beta1: a.beta1,
            beta2: a.beta2,
            eps: a.eps,
        },
        from_bytes(&a.m, "adam m")?,
        from_bytes(&a.v, "adam v")?,
        a.step,
    )
    .map_err(|e| format!("adam: {e}"))?;
    let trainer = Trainer::from_parts(online, target, adam).map_err(|e| e.to_string())?;
    let r = pl.replay;
    let replay = Replay::from_columns(
        r.capacity,
        r.humans,
        Columns {
            states: from_bytes(&r.states, "replay states")?,
            next_states: from_bytes(&r.next_states, "replay next states")?,
            rewards: from_bytes(&r.rewards, "replay rewards")?,
            discounts: from_bytes(&r.discounts, "replay discounts")?,
            returns: from_bytes(&r.returns, "replay returns")?,
            next: r.next,
        },
    )
    .ok_or("replay columns do not fit together")?;
    let mut rng = ChaCha8Rng::from_seed(pl.rng.seed);
    rng.set_stream(pl.rng.stream);
    rng.set_word_pos(((pl.rng.word_pos_hi as u128) << 64) | pl.rng.word_pos_lo as u128);
    let counters = Counters::from(pl.counters);
    let problems = pl.train.problems();
    if !problems.is_empty() {
        return Err(format!("training config: {}", problems.join("; ")));
    }
    pl.sim.validate().map_err(|e| e.to_string())?;
    let mut core = LearnerCore::assemble(
        pl.method,
        pl.train,
        trainer,
        replay,
        rng,
        counters,
        pl.sim.dt_s,
    );
    // Cached targets are not stored: they follow from the target network, before the next update.
    core.invalidate_targets();
    Ok(Loaded {
        core,
        sim: pl.sim,
        run: pl.run,
    })
}
