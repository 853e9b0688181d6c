//! Transport configuration (serde, `deny_unknown_fields`; roles embed it in their TOML).

use std::time::Duration;

use proto::{RunId, SenderId};
use serde::{Deserialize, Serialize};

use crate::error::TransportError;

/// Where the data plane (transitions, weights, control, acks) travels.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum DataPlane {
    /// zenoh for everything (any number of machines).
    #[default]
    Zenoh,
    /// iceoryx2 shared memory for the data plane (one machine); telemetry and liveliness stay
    /// on zenoh (loopback).
    Iceoryx2,
}

/// zenoh session mode.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum ZenohMode {
    /// Peer: talks directly to the peers it listens for / connects to.
    #[default]
    Peer,
    /// Client of a router (`zenohd`) given in `connect`.
    Client,
}

/// zenoh session settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ZenohConfig {
    /// Peer (default) or client.
    pub mode: ZenohMode,
    /// Endpoints to listen on, e.g. `tcp/127.0.0.1:7447`. Default: loopback, ephemeral port
    /// (`tcp/127.0.0.1:0`) in peer mode, nothing in client mode.
    pub listen: Vec<String>,
    /// Endpoints to connect to (the learner's listen endpoint, or the router).
    pub connect: Vec<String>,
    /// Multicast scouting (UDP 224.0.0.224:7446). Off by default: explicit endpoints only.
    pub multicast_scouting: bool,
    /// How long a blocked reliable publication waits for a full receiver before zenoh closes
    /// the link (zenoh `congestion_control/block/wait_before_close`), in ms.
    pub block_timeout_ms: u64,
    /// Extra raw zenoh settings `(key path, JSON5 value)`, applied last, e.g.
    /// `("transport/link/tx/lease", "20000")`.
    pub overrides: Vec<(String, String)>,
}

impl Default for ZenohConfig {
    fn default() -> Self {
        Self {
            mode: ZenohMode::Peer,
            listen: vec!["tcp/127.0.0.1:0".into()],
            connect: Vec::new(),
            multicast_scouting: false,
            block_timeout_ms: 10_000,
            overrides: Vec::new(),
        }
    }
}

impl ZenohConfig {
    /// A client of the router at `endpoint` (e.g. `tcp/10.0.0.5:7447`).
    pub fn client(endpoint: impl Into<String>) -> Self {
        Self {
            mode: ZenohMode::Client,
            listen: Vec::new(),
            connect: vec![endpoint.into()],
            ..Self::default()
        }
    }

    /// A peer listening on `listen` and connecting to `connect`.
    pub fn peer(listen: Vec<String>, connect: Vec<String>) -> Self {
        Self {
            listen,
            connect,
            ..Self::default()
        }
    }

    pub(crate) fn to_zenoh(
        &self,
        max_message_bytes: usize,
    ) -> Result<zenoh::Config, TransportError> {
        let mut c = zenoh::Config::default();
        let json = |v: &[String]| {
            serde_json::to_string(v).map_err(|e| TransportError::Config(e.to_string()))
        };
        let mut set = |key: &str, value: String| {
            c.insert_json5(key, &value)
                .map_err(|e| TransportError::Config(format!("zenoh {key} = {value}: {e}")))
        };
        set(
            "mode",
            match self.mode {
                ZenohMode::Peer => "\"peer\"".into(),
                ZenohMode::Client => "\"client\"".into(),
            },
        )?;
        set("listen/endpoints", json(&self.listen)?)?;
        set("connect/endpoints", json(&self.connect)?)?;
        set(
            "scouting/multicast/enabled",
            self.multicast_scouting.to_string(),
        )?;
        set(
            "transport/link/tx/queue/congestion_control/block/wait_before_close",
            (self.block_timeout_ms.saturating_mul(1000)).to_string(),
        )?;
        // Reject oversized messages at defragmentation already (default would be 1 GiB).
        set(
            "transport/link/rx/max_message_size",
            (max_message_bytes + 64 * 1024).to_string(),
        )?;
        for (k, v) in &self.overrides {
            set(k, v.clone())?;
        }
        Ok(c)
    }
}

/// iceoryx2 settings (used when `data_plane = "iceoryx2"`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct IceoryxConfig {
    /// Most processes of a run on this machine (actors + learner + evaluator + tools): sizes
    /// the publisher, subscriber and node limits of every service.
    pub max_processes: usize,
    /// Most subscribers of a many-to-one topic (the learner plus tools).
    pub max_collectors: usize,
    /// Samples a subscriber of a reliable topic can queue before publishers block.
    pub subscriber_buffer: usize,
    /// Initial sample size of reliable topics, in bytes (grows by powers of two).
    pub initial_sample_bytes: usize,
    /// Fixed sample size of latest-value topics (weights, control), in bytes: must hold the
    /// largest encoded weights (SARL: ~0.39 MB).
    pub latest_sample_bytes: usize,
    /// File-name prefix of every iceoryx2 resource (shared memory, files). Default:
    /// `fsrl_<run>_`, so runs never see each other.
    pub prefix: Option<String>,
    /// Directory of iceoryx2's files. Default: iceoryx2's (`/tmp/iceoryx2/`).
    pub root_path: Option<String>,
}

impl Default for IceoryxConfig {
    fn default() -> Self {
        Self {
            max_processes: 32,
            max_collectors: 4,
            subscriber_buffer: 64,
            initial_sample_bytes: 32 * 1024,
            latest_sample_bytes: 1024 * 1024,
            prefix: None,
            root_path: None,
        }
    }
}

/// Everything [`crate::Transport::open`] needs.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TransportConfig {
    /// The run (first key chunk after `fsrl/`).
    pub run: RunId,
    /// Who this process is.
    pub sender: SenderId,
    /// Data plane.
    #[serde(default)]
    pub data_plane: DataPlane,
    /// zenoh session (always opened: telemetry and liveliness).
    #[serde(default)]
    pub zenoh: ZenohConfig,
    /// iceoryx2 settings.
    #[serde(default)]
    pub iceoryx2: IceoryxConfig,
    /// Largest message sent or accepted, in bytes.
    #[serde(default = "default_max_message_bytes")]
    pub max_message_bytes: usize,
    /// How long a reliable publication may block on a full receiver before failing, in ms.
    #[serde(default = "default_publish_timeout_ms")]
    pub publish_timeout_ms: u64,
    /// Capacity of a zenoh subscriber's receive queue (messages); when full, zenoh pushes back
    /// on reliable publishers.
    #[serde(default = "default_subscriber_queue")]
    pub subscriber_queue: usize,
}

fn default_max_message_bytes() -> usize {
    proto::DEFAULT_MAX_MESSAGE_BYTES
}
fn default_publish_timeout_ms() -> u64 {
    10_000
}
fn default_subscriber_queue() -> usize {
    1024
}

impl TransportConfig {
    /// Defaults: zenoh data plane, peer on loopback with an ephemeral port, no multicast.
    pub fn new(run: RunId, sender: SenderId) -> Self {
        Self {
            run,
            sender,
            data_plane: DataPlane::Zenoh,
            zenoh: ZenohConfig::default(),
            iceoryx2: IceoryxConfig::default(),
            max_message_bytes: default_max_message_bytes(),
            publish_timeout_ms: default_publish_timeout_ms(),
            subscriber_queue: default_subscriber_queue(),
        }
    }

    /// `publish_timeout_ms` as a duration.
    pub fn publish_timeout(&self) -> Duration {
        Duration::from_millis(self.publish_timeout_ms)
    }

    /// Checks the configuration, reporting every problem at once.
    pub fn validate(&self) -> Result<(), TransportError> {
        let mut problems = Vec::new();
        if self.max_message_bytes < 1024 {
            problems.push("max_message_bytes must be at least 1024".to_string());
        }
        if self.subscriber_queue == 0 {
            problems.push("subscriber_queue must be positive".into());
        }
        if self.zenoh.mode == ZenohMode::Client && self.zenoh.connect.is_empty() {
            problems.push("zenoh client mode needs a `connect` endpoint (the router)".into());
        }
        let i = &self.iceoryx2;
        if i.max_processes < 2 {
            problems.push("iceoryx2.max_processes must be at least 2".into());
        }
        if i.max_collectors == 0 || i.subscriber_buffer == 0 {
            problems.push("iceoryx2.max_collectors and subscriber_buffer must be positive".into());
        }
        if i.initial_sample_bytes < 64 || i.latest_sample_bytes < 64 {
            problems.push("iceoryx2 sample sizes must be at least 64 bytes".into());
        }
        if i.latest_sample_bytes > self.max_message_bytes {
            problems.push("iceoryx2.latest_sample_bytes exceeds max_message_bytes".into());
        }
        if let Some(p) = &i.prefix {
            if p.is_empty()
                || !p
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.'))
            {
                problems.push(format!("iceoryx2.prefix {p:?} must be [A-Za-z0-9_.-]+"));
            }
        }
        if problems.is_empty() {
            Ok(())
        } else {
            Err(TransportError::Config(problems.join("; ")))
        }
    }
}
