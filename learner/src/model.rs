//! Model files (`.fsrlm`): a trained policy to ship, weights only. A model holds the method, the
//! online network (description and weights), the setting it was trained in, run id and seed,
//! the resolved training and simulator configs, the counters, and a *check*: what the greedy
//! policy did on recorded test seeds of its trained setting at export time (outcome, steps,
//! return per episode), so anyone can prove a shipped model still reproduces its record
//! ([`Model::run_check`]). A checkpoint (~100 MB with its replay) becomes a model of a few
//! hundred KB with [`Model::from_checkpoint`] and [`Model::record_check`].
//!
//! File layout (`frame.rs`): `b"FSRLMODL"`, [`FORMAT_VERSION`] (u32 LE), payload length
//! (u64 LE), payload (MessagePack with field names: `method`, `net` (as in checkpoints),
//! `weights` (f32 LE bytes in flat layout order), `setting`, `run_id`, `run_seed`, `train`,
//! `sim`, `counters`, `check` (list of `{seed, outcome, steps, return_sum}`)), CRC-32 of the
//! payload (u32 LE). Reading a truncated, corrupt, other-version or inconsistent file (weights
//! that do not fit the network description, a network the method does not use) is an error,
//! never a panic. [`load_policy`] reads a model or a checkpoint, telling them apart by their
//! first bytes.

use std::ops::Range;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use policy::config::NetConfig;
use policy::method::{Method, TrainConfig};
use policy::rollout::{rollout, Behaviour};
use policy::ValueNet;
use sim::{Env, Outcome, Setting, SimConfig};

use crate::checkpoint::{self, from_bytes, to_bytes, CheckpointError, CountersRec, NetDesc};
use crate::core::{Counters, LearnerCore};
use crate::frame::{self, FrameError};

const MAGIC: &[u8; 8] = b"FSRLMODL";
/// Bumped whenever the payload changes incompatibly.
pub const FORMAT_VERSION: u32 = 1;
/// The conventional file extension (without the dot); readers go by content, not by name.
pub const EXTENSION: &str = "fsrlm";
/// The directory of a run's validation snapshots (`train.select`): the trainer of a
/// single-process run and the evaluator process of a distributed one write them.
pub fn snapshot_dir(run_dir: &Path) -> PathBuf {
    run_dir.join("checkpoints").join("validation")
}

/// The snapshot file of the validation after `rl_episodes` RL episodes.
pub fn snapshot_path(run_dir: &Path, rl_episodes: u64) -> PathBuf {
    snapshot_dir(run_dir).join(format!("ep-{rl_episodes:06}.{EXTENSION}"))
}

/// Check episodes recorded by default, seeds [`DEFAULT_CHECK_SEED_START`]`..`.
pub const DEFAULT_CHECK_EPISODES: u32 = 20;
/// The first test seed (CrowdNav's test seeds start at 1000).
pub const DEFAULT_CHECK_SEED_START: u64 = 1000;

/// Why bytes are not a model.
#[derive(Debug, thiserror::Error)]
pub enum FormatError {
    #[error("not an fsrl model file (bad magic bytes)")]
    NotAModel,
    #[error("model format version {found}, this build reads version {expected}")]
    Version { found: u32, expected: u32 },
    #[error("truncated model file ({got} bytes, expected {expected})")]
    Truncated { got: u64, expected: u64 },
    #[error("corrupt model file (checksum mismatch)")]
    Corrupt,
    #[error("cannot decode model: {0}")]
    Decode(String),
    #[error("cannot encode model: {0}")]
    Encode(String),
    #[error("inconsistent model: {0}")]
    Mismatch(String),
}

/// Why a model could not be made, written, read or checked.
#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    // The cause is part of the message (not a `source`), so error chains do not repeat it.
    #[error("{path}: {error}")]
    Io {
        path: PathBuf,
        error: std::io::Error,
    },
    #[error("{path}: {error}")]
    Format { path: PathBuf, error: FormatError },
    #[error(transparent)]
    Checkpoint(#[from] CheckpointError),
    #[error("{0}: neither an fsrl model file nor a checkpoint (unrecognised first bytes)")]
    UnknownKind(PathBuf),
    #[error("{0}")]
    Invalid(String),
    #[error("running the check episodes: {0}")]
    Check(String),
    #[error("the model does not reproduce its check: {}", .0.join("; "))]
    CheckMismatch(Vec<String>),
}

/// One greedy test episode of the model's trained setting, as recorded at export.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CheckEpisode {
    pub seed: u64,
    /// Never `Running`.
    pub outcome: Outcome,
    pub steps: u32,
    /// Undiscounted sum of the rewards (`EpisodeSummary::return_sum`).
    pub return_sum: f64,
}

/// A trained policy with where it came from and its recorded check.
#[derive(Debug, Clone)]
pub struct Model {
    pub method: Method,
    /// The online network (its description is `net.config()`).
    pub net: ValueNet,
    /// The setting it was trained in.
    pub setting: Setting,
    pub run_id: String,
    pub run_seed: u64,
    pub train: TrainConfig,
    /// The simulator config of the run, with the method's reward switches applied (what
    /// `Method::sim_config` gives; applying them again changes nothing).
    pub sim: SimConfig,
    pub counters: Counters,
    /// Empty until [`Model::record_check`].
    pub check: Vec<CheckEpisode>,
}

/// What a policy file is, by its first bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ArtifactKind {
    Checkpoint,
    Model,
}

#[derive(Serialize, Deserialize)]
struct CheckRec {
    seed: u64,
    outcome: String,
    steps: u32,
    return_sum: f64,
}

#[derive(Serialize, Deserialize)]
struct Payload {
    method: Method,
    net: NetDesc,
    #[serde(with = "serde_bytes")]
    weights: Vec<u8>,
    setting: String,
    run_id: String,
    run_seed: u64,
    train: TrainConfig,
    sim: SimConfig,
    counters: CountersRec,
    check: Vec<CheckRec>,
}

fn outcome_from_name(name: &str) -> Option<Outcome> {
    [Outcome::Collision, Outcome::ReachGoal, Outcome::Timeout]
        .into_iter()
        .find(|o| o.name() == name)
}

impl Model {
    /// The model of `core`'s online network in a run of `setting` (a setting name, as
    /// `RunInfo::setting`) with simulator config `sim` (before or after the method's switches).
    /// No check yet.
    pub fn from_core(
        core: &LearnerCore,
        sim: &SimConfig,
        run: &checkpoint::RunInfo,
    ) -> Result<Self, ModelError> {
        let setting = run
            .setting
            .parse::<Setting>()
            .map_err(|e| ModelError::Invalid(e.to_string()))?;
        let model = Self {
            method: core.method(),
            net: core.online().clone(),
            setting,
            run_id: run.run_id.clone(),
            run_seed: run.run_seed,
            train: core.config().clone(),
            sim: core.method().sim_config(sim),
            counters: core.counters(),
            check: Vec::new(),
        };
        model.validate().map_err(ModelError::Invalid)?;
        Ok(model)
    }

    /// The model of weights scored outside the learner (the evaluator process keeps every
    /// validated snapshot): `net` at weights `version` after `rl_episodes` RL episodes of the
    /// run `spec`. The evaluator knows only these counters of the learner's; env steps and
    /// updates are left at zero. No check yet.
    pub fn from_snapshot(
        spec: &policy::method::RunSpec,
        run_id: &str,
        net: &policy::ValueNet,
        version: u64,
        rl_episodes: u64,
    ) -> Result<Self, ModelError> {
        let model = Self {
            method: spec.method,
            net: net.clone(),
            setting: spec.setting,
            run_id: run_id.to_string(),
            run_seed: spec.seed,
            train: spec.train.clone(),
            sim: spec.method.sim_config(&spec.sim),
            counters: Counters {
                demo_episodes: spec.train.imitation.episodes,
                imitation_done: true,
                rl_episodes,
                updates: 0,
                env_steps: 0,
                policy_version: version,
            },
            check: Vec::new(),
        };
        model.validate().map_err(ModelError::Invalid)?;
        Ok(model)
    }

    /// The model of a loaded checkpoint (no check yet).
    pub fn from_checkpoint(loaded: &checkpoint::Loaded) -> Result<Self, ModelError> {
        Self::from_core(&loaded.core, &loaded.sim, &loaded.run)
    }

    /// Everything that must hold for a model to be written or read.
    fn validate(&self) -> Result<(), String> {
        let net = self.net.config();
        if self.method.net().map(|n| n.kind()) != Some(net.kind()) {
            return Err(format!(
                "method {} does not use a {} network",
                self.method,
                net.kind().name()
            ));
        }
        let problems = self.train.problems();
        if !problems.is_empty() {
            return Err(format!("training config: {}", problems.join("; ")));
        }
        self.sim.validate().map_err(|e| e.to_string())?;
        self.sim
            .resolve_settings(&[self.setting.name()])
            .map_err(|e| e.to_string())?;
        if let Some(e) = self.check.iter().find(|e| e.outcome == Outcome::Running) {
            return Err(format!("check episode seed {} did not end", e.seed));
        }
        Ok(())
    }

    /// The simulator config the policy runs with.
    pub fn method_sim(&self) -> SimConfig {
        self.method.sim_config(&self.sim)
    }

    /// Runs the greedy policy (ε = 0, the evaluator's rollout) on `seeds` of the trained
    /// setting with up to `threads` threads; one entry per seed, in seed order.
    pub fn check_episodes(
        &self,
        seeds: Range<u64>,
        threads: usize,
    ) -> Result<Vec<CheckEpisode>, ModelError> {
        let seeds: Vec<u64> = seeds.collect();
        self.run_seeds(&seeds, threads)
    }

    fn run_seeds(&self, seeds: &[u64], threads: usize) -> Result<Vec<CheckEpisode>, ModelError> {
        let cfg = self.method_sim();
        let threads = threads.clamp(1, seeds.len().max(1));
        let parts = std::thread::scope(|scope| {
            let handles: Vec<_> = (0..threads)
                .map(|w| {
                    let cfg = &cfg;
                    scope.spawn(move || -> Result<Vec<(usize, CheckEpisode)>, String> {
                        let mut out = Vec::new();
                        let mut env: Option<Env> = None;
                        let mut lookahead = self.train.lookahead(self.method.human_order());
                        for (i, &seed) in seeds.iter().enumerate().skip(w).step_by(threads) {
                            let env = match &mut env {
                                Some(env) => env,
                                slot => slot.insert(
                                    Env::new(cfg.clone(), self.setting, seed)
                                        .map_err(|e| e.to_string())?,
                                ),
                            };
                            let ep = rollout(
                                env,
                                seed,
                                Behaviour::Net {
                                    net: &self.net,
                                    lookahead: &mut lookahead,
                                    epsilon: 0.0,
                                    policy_version: self.counters.policy_version,
                                },
                            )
                            .map_err(|e| format!("seed {seed}: {e}"))?;
                            out.push((
                                i,
                                CheckEpisode {
                                    seed,
                                    outcome: ep.summary.outcome,
                                    steps: ep.summary.steps,
                                    return_sum: ep.summary.return_sum,
                                },
                            ));
                        }
                        Ok(out)
                    })
                })
                .collect();
            handles
                .into_iter()
                .map(|h| {
                    h.join()
                        .map_err(|_| "a check thread panicked".to_string())?
                })
                .collect::<Result<Vec<_>, String>>()
        })
        .map_err(ModelError::Check)?;
        let mut all: Vec<(usize, CheckEpisode)> = parts.into_iter().flatten().collect();
        all.sort_by_key(|(i, _)| *i);
        Ok(all.into_iter().map(|(_, e)| e).collect())
    }

    /// Records the check: `episodes` greedy episodes on seeds `seed_start..` of the trained
    /// setting.
    pub fn record_check(
        &mut self,
        seed_start: u64,
        episodes: u32,
        threads: usize,
    ) -> Result<(), ModelError> {
        let end = seed_start
            .checked_add(episodes as u64)
            .ok_or_else(|| ModelError::Invalid("check seeds overflow u64".into()))?;
        self.check = self.check_episodes(seed_start..end, threads)?;
        Ok(())
    }

    /// Runs the recorded check seeds again (same order as [`Model::check`]).
    pub fn run_check(&self, threads: usize) -> Result<Vec<CheckEpisode>, ModelError> {
        let seeds: Vec<u64> = self.check.iter().map(|e| e.seed).collect();
        self.run_seeds(&seeds, threads)
    }

    /// Runs the check again and compares: same outcomes and steps, returns within
    /// `return_tolerance`; every difference is listed in the error.
    pub fn verify_check(&self, threads: usize, return_tolerance: f64) -> Result<(), ModelError> {
        let again = self.run_check(threads)?;
        let diffs = check_differences(&self.check, &again, return_tolerance);
        if diffs.is_empty() {
            Ok(())
        } else {
            Err(ModelError::CheckMismatch(diffs))
        }
    }

    /// The file's bytes.
    pub fn encode(&self) -> Result<Vec<u8>, FormatError> {
        self.validate().map_err(FormatError::Mismatch)?;
        let payload = Payload {
            method: self.method,
            net: NetDesc::from(self.net.config()),
            weights: to_bytes(self.net.params()),
            setting: self.setting.name().to_string(),
            run_id: self.run_id.clone(),
            run_seed: self.run_seed,
            train: self.train.clone(),
            sim: self.sim.clone(),
            counters: self.counters.into(),
            check: self
                .check
                .iter()
                .map(|e| CheckRec {
                    seed: e.seed,
                    outcome: e.outcome.name().to_string(),
                    steps: e.steps,
                    return_sum: e.return_sum,
                })
                .collect(),
        };
        let body =
            rmp_serde::to_vec_named(&payload).map_err(|e| FormatError::Encode(e.to_string()))?;
        Ok(frame::seal(MAGIC, FORMAT_VERSION, &body))
    }

    /// Reads [`Model::encode`]'s output.
    pub fn decode(bytes: &[u8]) -> Result<Self, FormatError> {
        let body = frame::open(bytes, MAGIC, FORMAT_VERSION).map_err(|e| match e {
            FrameError::BadMagic => FormatError::NotAModel,
            FrameError::Version(found) => FormatError::Version {
                found,
                expected: FORMAT_VERSION,
            },
            FrameError::Truncated { got, expected } => FormatError::Truncated { got, expected },
            FrameError::Corrupt => FormatError::Corrupt,
        })?;
        let pl: Payload =
            rmp_serde::from_slice(body).map_err(|e| FormatError::Decode(e.to_string()))?;
        Self::rebuild(pl).map_err(FormatError::Mismatch)
    }

    fn rebuild(pl: Payload) -> Result<Self, String> {
        let net_cfg = NetConfig::from(pl.net);
        if pl.method.net().map(|n| n.kind()) != Some(net_cfg.kind()) {
            return Err(format!(
                "method {} does not use a {} network",
                pl.method,
                net_cfg.kind().name()
            ));
        }
        let net = ValueNet::from_params(net_cfg, from_bytes(&pl.weights, "weights")?)
            .map_err(|e| format!("weights: {e}"))?;
        let setting = pl.setting.parse::<Setting>().map_err(|e| e.to_string())?;
        let check = pl
            .check
            .into_iter()
            .map(|r| {
                Ok(CheckEpisode {
                    seed: r.seed,
                    outcome: outcome_from_name(&r.outcome).ok_or_else(|| {
                        format!("check episode seed {}: outcome `{}`", r.seed, r.outcome)
                    })?,
                    steps: r.steps,
                    return_sum: r.return_sum,
                })
            })
            .collect::<Result<Vec<_>, String>>()?;
        let model = Self {
            method: pl.method,
            net,
            setting,
            run_id: pl.run_id,
            run_seed: pl.run_seed,
            train: pl.train,
            sim: pl.sim,
            counters: pl.counters.into(),
            check,
        };
        model.validate()?;
        Ok(model)
    }

    /// Writes the model to `path` atomically (a temporary file beside it, synced, renamed).
    pub fn save(&self, path: &Path) -> Result<(), ModelError> {
        let bytes = self.encode().map_err(|error| ModelError::Format {
            path: path.to_path_buf(),
            error,
        })?;
        let mut tmp = path.as_os_str().to_owned();
        tmp.push(".tmp");
        let tmp = PathBuf::from(tmp);
        frame::replace(path, &tmp, &[&bytes])
            .map_err(|(path, error)| ModelError::Io { path, error })
    }

    /// Reads a model file.
    pub fn load(path: &Path) -> Result<Self, ModelError> {
        Self::decode_file(path, &read(path)?)
    }

    /// [`Model::decode`] of a file's bytes, its errors naming `path`.
    fn decode_file(path: &Path, bytes: &[u8]) -> Result<Self, ModelError> {
        Self::decode(bytes).map_err(|error| ModelError::Format {
            path: path.to_path_buf(),
            error,
        })
    }
}

/// A whole file, its error naming `path`.
fn read(path: &Path) -> Result<Vec<u8>, ModelError> {
    std::fs::read(path).map_err(|error| ModelError::Io {
        path: path.to_path_buf(),
        error,
    })
}

/// Every difference between a recorded check and a replay of it.
pub fn check_differences(
    recorded: &[CheckEpisode],
    replayed: &[CheckEpisode],
    return_tolerance: f64,
) -> Vec<String> {
    let mut d = Vec::new();
    if recorded.len() != replayed.len() {
        d.push(format!(
            "{} episodes recorded, {} replayed",
            recorded.len(),
            replayed.len()
        ));
    }
    for (r, p) in recorded.iter().zip(replayed) {
        if r.seed != p.seed {
            d.push(format!("seed {} replayed as seed {}", r.seed, p.seed));
        } else if r.outcome != p.outcome || r.steps != p.steps {
            d.push(format!(
                "seed {}: recorded {} after {} steps, now {} after {}",
                r.seed,
                r.outcome.name(),
                r.steps,
                p.outcome.name(),
                p.steps
            ));
        } else if !within(r.return_sum, p.return_sum, return_tolerance) {
            d.push(format!(
                "seed {}: recorded return {}, now {}",
                r.seed, r.return_sum, p.return_sum
            ));
        }
    }
    d
}

/// `a` and `b` differ by at most `tolerance` (NaN never does).
fn within(a: f64, b: f64, tolerance: f64) -> bool {
    (a - b).abs() <= tolerance
}

/// A model file or a checkpoint, by the file's first bytes (`None`: neither).
pub fn sniff(path: &Path) -> Result<Option<ArtifactKind>, ModelError> {
    use std::io::Read;
    let io = |error| ModelError::Io {
        path: path.to_path_buf(),
        error,
    };
    let mut head = Vec::with_capacity(8);
    std::fs::File::open(path)
        .map_err(io)?
        .take(8)
        .read_to_end(&mut head)
        .map_err(io)?;
    Ok(kind_of(&head))
}

/// A model file or a checkpoint, by its first bytes (`None`: neither).
fn kind_of(bytes: &[u8]) -> Option<ArtifactKind> {
    let head = bytes.get(..8)?;
    if head == MAGIC {
        Some(ArtifactKind::Model)
    } else if head == checkpoint::MAGIC {
        Some(ArtifactKind::Checkpoint)
    } else {
        None
    }
}

/// [`load_policy`] of a file's bytes already read (`path` names them in errors): a caller that
/// also hashes the file reads it once, and the weights it loads are the bytes it hashed.
pub fn policy_from_bytes(path: &Path, bytes: &[u8]) -> Result<(Model, ArtifactKind), ModelError> {
    match kind_of(bytes) {
        Some(ArtifactKind::Model) => Ok((Model::decode_file(path, bytes)?, ArtifactKind::Model)),
        Some(ArtifactKind::Checkpoint) => Ok((
            Model::from_checkpoint(&checkpoint::decode(path, bytes)?)?,
            ArtifactKind::Checkpoint,
        )),
        None => Err(ModelError::UnknownKind(path.to_path_buf())),
    }
}

/// The policy in a model file or a checkpoint (read whole, then reduced to the model of its
/// online network, with an empty check), and which of the two it was.
pub fn load_policy(path: &Path) -> Result<(Model, ArtifactKind), ModelError> {
    policy_from_bytes(path, &read(path)?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use policy::config::{LstmRlConfig, SarlConfig};

    fn setting() -> Setting {
        "env1-invisible".parse().unwrap()
    }

    fn run_info() -> checkpoint::RunInfo {
        checkpoint::RunInfo {
            run_id: "unit".into(),
            setting: setting().name().into(),
            run_seed: 3,
            accepted_below: Default::default(),
        }
    }

    fn fresh(method: Method) -> Model {
        let mut train = TrainConfig::default();
        train.rl.replay_capacity = 10;
        let sim = SimConfig::default();
        let core = LearnerCore::new(method, train, sim.humans.count, sim.dt_s, 3).unwrap();
        let mut m = Model::from_core(&core, &sim, &run_info()).unwrap();
        m.check = vec![
            CheckEpisode {
                seed: 1000,
                outcome: Outcome::Timeout,
                steps: 100,
                return_sum: -0.2,
            },
            CheckEpisode {
                seed: 1001,
                outcome: Outcome::ReachGoal,
                steps: 41,
                return_sum: 0.875_123_456_789,
            },
        ];
        m
    }

    fn same(a: &Model, b: &Model) {
        assert_eq!(a.method, b.method);
        assert_eq!(a.net.config(), b.net.config());
        let bits = |m: &Model| {
            m.net
                .params()
                .iter()
                .map(|x| x.to_bits())
                .collect::<Vec<_>>()
        };
        assert_eq!(bits(a), bits(b));
        assert_eq!(a.setting, b.setting);
        assert_eq!(
            (&a.run_id, a.run_seed, &a.train, &a.sim, a.counters),
            (&b.run_id, b.run_seed, &b.train, &b.sim, b.counters)
        );
        assert_eq!(a.check, b.check);
    }

    fn payload(m: &Model) -> Payload {
        let bytes = m.encode().unwrap();
        let body = frame::open(&bytes, MAGIC, FORMAT_VERSION).unwrap();
        rmp_serde::from_slice(body).unwrap()
    }

    fn reseal(pl: &Payload) -> Vec<u8> {
        frame::seal(MAGIC, FORMAT_VERSION, &rmp_serde::to_vec_named(pl).unwrap())
    }

    #[test]
    fn models_round_trip_bit_exact() {
        for method in [Method::Fsrl, Method::LstmRl] {
            let m = fresh(method);
            assert!(m.sim.reward.foresight == (method == Method::Fsrl));
            let bytes = m.encode().unwrap();
            // Weights only: a few hundred KB at most, far from a checkpoint.
            assert!(
                bytes.len() < 4 * m.net.num_params() + 16_384,
                "{}",
                bytes.len()
            );
            let back = Model::decode(&bytes).unwrap();
            same(&m, &back);
            assert_eq!(back.encode().unwrap(), bytes, "encoding is canonical");
        }
    }

    #[test]
    fn damaged_files_are_errors_never_panics() {
        let m = fresh(Method::Fsrl);
        let bytes = m.encode().unwrap();
        assert!(matches!(
            Model::decode(&bytes[..bytes.len() - 1]),
            Err(FormatError::Truncated { .. })
        ));
        assert!(matches!(
            Model::decode(&bytes[..3]),
            Err(FormatError::NotAModel)
        ));
        let mut flipped = bytes.clone();
        flipped[bytes.len() / 2] ^= 0x40;
        assert!(matches!(Model::decode(&flipped), Err(FormatError::Corrupt)));
        let mut other = bytes.clone();
        other[8] = 7;
        let e = Model::decode(&other).unwrap_err();
        assert!(e.to_string().contains("format version 7"), "{e}");
        // A checkpoint's magic is not a model's.
        let mut ckpt = bytes.clone();
        ckpt[..8].copy_from_slice(checkpoint::MAGIC);
        assert!(matches!(Model::decode(&ckpt), Err(FormatError::NotAModel)));
        // Garbage payloads behind a valid frame decode to errors.
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let body = &bytes[frame::HEADER..bytes.len() - 4];
        for _ in 0..300 {
            let mut b = body.to_vec();
            match rng.gen_range(0..3) {
                0 => b.truncate(rng.gen_range(0..b.len())),
                1 => {
                    let i = rng.gen_range(0..b.len());
                    b[i] = rng.gen();
                }
                _ => b = (0..rng.gen_range(0..64)).map(|_| rng.gen()).collect(),
            }
            // Either a clean error or (a flipped weight byte) a model that still decodes.
            let _ = Model::decode(&frame::seal(MAGIC, FORMAT_VERSION, &b));
        }
    }

    #[test]
    fn inconsistent_contents_are_refused() {
        let m = fresh(Method::Fsrl);
        let mismatch = |pl: &Payload, what: &str| {
            let e = Model::decode(&reseal(pl)).expect_err("must not decode");
            assert!(matches!(e, FormatError::Mismatch(_)), "{e}");
            assert!(e.to_string().contains(what), "{e} lacks {what}");
        };
        // Weights that do not fit the description: one short, or a bigger network described.
        let mut pl = payload(&m);
        pl.weights.truncate(pl.weights.len() - 4);
        mismatch(&pl, "weights");
        let mut pl = payload(&m);
        pl.net = NetDesc::from(&NetConfig::Sarl(SarlConfig {
            mlp1_dims: vec![150, 120],
            ..SarlConfig::default()
        }));
        mismatch(&pl, "weights");
        let mut pl = payload(&m);
        pl.weights.push(0);
        mismatch(&pl, "whole number of f32");
        // A network the method does not use.
        let mut pl = payload(&m);
        pl.net = NetDesc::from(&NetConfig::LstmRl(LstmRlConfig {
            hidden_dim: 50,
            mlp_dims: vec![150, 100, 100, 1],
        }));
        mismatch(&pl, "does not use");
        let mut pl = payload(&m);
        pl.method = Method::Orca;
        mismatch(&pl, "does not use");
        // Non-finite weights, unknown names, an invalid config.
        let mut pl = payload(&m);
        pl.weights[..4].copy_from_slice(&f32::NAN.to_le_bytes());
        mismatch(&pl, "weights");
        let mut pl = payload(&m);
        pl.setting = "env4-visible".into();
        mismatch(&pl, "env4-visible");
        let mut pl = payload(&m);
        pl.check[0].outcome = "running".into();
        mismatch(&pl, "outcome `running`");
        let mut pl = payload(&m);
        pl.train.gamma = 2.0;
        mismatch(&pl, "train.gamma");
        // A payload that is not a model at all.
        let e =
            Model::decode(&frame::seal(MAGIC, FORMAT_VERSION, b"\x93\x01\x02\x03")).unwrap_err();
        assert!(matches!(e, FormatError::Decode(_)), "{e}");
        // Nor can an inconsistent model be written.
        let mut bad = m.clone();
        bad.method = Method::LstmRl;
        assert!(matches!(bad.encode(), Err(FormatError::Mismatch(_))));
    }

    #[test]
    fn files_are_written_atomically_and_told_apart_by_content() {
        let dir = tempfile::tempdir().unwrap();
        let m = fresh(Method::Sarl);
        // The extension does not matter; the content does.
        let path = dir.path().join("policy.bin");
        m.save(&path).unwrap();
        assert!(!dir.path().join("policy.bin.tmp").exists());
        assert_eq!(sniff(&path).unwrap(), Some(ArtifactKind::Model));
        let (back, kind) = load_policy(&path).unwrap();
        assert_eq!(kind, ArtifactKind::Model);
        same(&m, &back);

        let core = LearnerCore::new(
            Method::Sarl,
            m.train.clone(),
            m.sim.humans.count,
            m.sim.dt_s,
            3,
        )
        .unwrap();
        let ckpt = dir.path().join("run.fsrlm");
        checkpoint::save(&ckpt, &core, &m.sim, &run_info()).unwrap();
        assert_eq!(sniff(&ckpt).unwrap(), Some(ArtifactKind::Checkpoint));
        let (from_ckpt, kind) = load_policy(&ckpt).unwrap();
        assert_eq!(kind, ArtifactKind::Checkpoint);
        assert!(from_ckpt.check.is_empty());
        assert_eq!(from_ckpt.net.params(), m.net.params());

        let junk = dir.path().join("junk.fsrlm");
        std::fs::write(&junk, b"FSRL").unwrap();
        assert_eq!(sniff(&junk).unwrap(), None);
        let e = load_policy(&junk).unwrap_err();
        assert!(e.to_string().contains("junk.fsrlm: neither"), "{e}");
        let e = load_policy(&dir.path().join("missing.fsrlm")).unwrap_err();
        assert!(e.to_string().contains("missing.fsrlm"), "{e}");
        let mut damaged = std::fs::read(&path).unwrap();
        damaged.truncate(damaged.len() - 10);
        std::fs::write(&junk, &damaged).unwrap();
        let e = load_policy(&junk).unwrap_err();
        assert!(
            e.to_string().contains("junk.fsrlm: truncated model file"),
            "{e}"
        );
        // An unwritable destination is an error naming the file.
        let e = m.save(&dir.path().join("no/such/dir/m.fsrlm")).unwrap_err();
        assert!(e.to_string().contains("m.fsrlm.tmp"), "{e}");
    }

    #[test]
    fn the_check_is_the_evaluators_numbers_and_replays() {
        let mut m = fresh(Method::Fsrl);
        m.record_check(1000, 3, 2).unwrap();
        assert_eq!(
            m.check.iter().map(|e| e.seed).collect::<Vec<_>>(),
            [1000, 1001, 1002]
        );
        // Thread count does not matter.
        assert_eq!(m.run_check(1).unwrap(), m.check);
        m.verify_check(3, 0.0).unwrap();
        // What evaluator::evaluate reports for the same policy and seeds.
        let subject = evaluator::Subject::learned(m.method, &m.net, &m.train);
        let r = evaluator::evaluate(subject, &m.sim, &[m.setting], 1000, 3, 1).unwrap();
        let a = r[0].aggregate;
        let count = |o| m.check.iter().filter(|e| e.outcome == o).count() as u32;
        assert_eq!(
            (a.successes, a.collisions, a.timeouts),
            (
                count(Outcome::ReachGoal),
                count(Outcome::Collision),
                count(Outcome::Timeout)
            )
        );
        assert_eq!(a.steps, m.check.iter().map(|e| e.steps as u64).sum::<u64>());
        let sum: f64 = m.check.iter().map(|e| e.return_sum).sum();
        assert!((a.return_sum - sum).abs() < 1e-9);
        // A tampered record is caught, every difference listed.
        let mut t = m.clone();
        t.check[0].steps += 1;
        t.check[2].return_sum += 1.0;
        match t.verify_check(1, 1e-6) {
            Err(ModelError::CheckMismatch(d)) => assert_eq!(d.len(), 2, "{d:?}"),
            other => panic!("{other:?}"),
        }
    }
}
