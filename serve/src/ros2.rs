//! Where ROS 2 topics live on zenoh, in the two ways ROS 2 meets zenoh:
//!
//! - [`Ros2Style::Bridge`] (`zenoh-bridge-ros2dds`): the key is the topic name without its
//!   leading `/`, optionally under a namespace (the bridge's `namespace` setting); the payload is
//!   the CDR message; no attachment.
//! - [`Ros2Style::RmwZenoh`] (`rmw_zenoh_cpp`, ROS 2 itself on zenoh): the key is
//!   `<domain>/<topic>/<dds type name>/<type hash>` (Humble: `TypeHashNotSupported`; Jazzy:
//!   `RIHS01_…`), every publication carries a 33-byte attachment ([`Attachment`]: sequence
//!   number, source timestamp, publisher GID), and every node, publisher and subscription
//!   declares a liveliness token under `@ros2_lv/…` ([`Ros2Style::liveliness`]) so that
//!   `ros2 node list` / `ros2 topic list` see them. Format from `rmw_zenoh_cpp`'s
//!   `liveliness_utils.cpp` and `attachment_helpers.cpp`; fixtures in
//!   `serve/tests/fixtures/rmw_zenoh.json`.

use crate::msg::{dds_type_name, RosMsg};

/// The ROS 2 distributions whose rmw_zenoh key layout is known.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Distro {
    /// No type hashes: keys end in `TypeHashNotSupported`.
    Humble,
    /// RIHS01 type hashes.
    Jazzy,
}

impl Distro {
    pub fn name(self) -> &'static str {
        match self {
            Distro::Humble => "humble",
            Distro::Jazzy => "jazzy",
        }
    }

    /// The type hash a key and a liveliness token carry for `M`.
    pub fn type_hash<M: RosMsg>(self) -> &'static str {
        match self {
            Distro::Humble => "TypeHashNotSupported",
            Distro::Jazzy => M::JAZZY_HASH,
        }
    }
}

impl std::str::FromStr for Distro {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "humble" => Ok(Distro::Humble),
            "jazzy" => Ok(Distro::Jazzy),
            _ => Err(format!("{s:?}: not humble or jazzy")),
        }
    }
}

/// How ROS 2 topics map onto zenoh keys.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Ros2Style {
    /// `zenoh-bridge-ros2dds`: `[<namespace>/]<topic>`.
    Bridge { namespace: Option<String> },
    /// `rmw_zenoh`: `<domain>/<topic>/<type>/<hash>` with attachments and liveliness.
    RmwZenoh { domain: u32, distro: Distro },
}

/// `/a/b/` → `a/b`; a topic name as a key.
fn strip_slashes(s: &str) -> &str {
    s.trim_start_matches('/').trim_end_matches('/')
}

/// Why a topic name cannot be a key.
pub fn check_topic(topic: &str) -> Result<(), String> {
    let t = strip_slashes(topic);
    let ok = !t.is_empty()
        && t.split('/').all(|p| {
            !p.is_empty()
                && p.chars()
                    .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '~')
        })
        && !t.starts_with(|c: char| c.is_ascii_digit());
    if ok {
        Ok(())
    } else {
        Err(format!(
            "{topic:?} is not a ROS 2 topic name (letters, digits, _ in /-separated parts)"
        ))
    }
}

impl Ros2Style {
    /// The zenoh key of `topic` (`odom`, `/robot1/cmd_vel`, ...) carrying `M`.
    pub fn key<M: RosMsg>(&self, topic: &str) -> String {
        let t = strip_slashes(topic);
        match self {
            Ros2Style::Bridge { namespace: None } => t.to_string(),
            Ros2Style::Bridge {
                namespace: Some(ns),
            } => format!("{}/{t}", strip_slashes(ns)),
            Ros2Style::RmwZenoh { domain, distro } => format!(
                "{domain}/{t}/{}/{}",
                dds_type_name(M::NAME),
                distro.type_hash::<M>()
            ),
        }
    }

    /// Whether publications carry an [`Attachment`].
    pub fn attaches(&self) -> bool {
        matches!(self, Ros2Style::RmwZenoh { .. })
    }
}

/// What a liveliness token announces.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Entity<'a> {
    Node,
    Publisher { topic: &'a str },
    Subscription { topic: &'a str },
}

/// `/` → `%` (rmw_zenoh's mangling of names inside one key chunk).
fn mangle(s: &str) -> String {
    s.replace('/', "%")
}

/// The default QoS (reliable, volatile, keep last 10) as rmw_zenoh writes it: every field
/// equal to the default is left empty.
pub const DEFAULT_QOS: &str = "::,:,:,:,,";

/// A node's identity in the graph.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct NodeId {
    /// The zenoh session id as rmw_zenoh prints it (lowercase hex).
    pub zid: String,
    /// Node id within the session.
    pub nid: u32,
    /// Namespace (`/` when none).
    pub namespace: String,
    pub name: String,
    /// Security enclave (`/` when none).
    pub enclave: String,
}

impl NodeId {
    /// `@ros2_lv/<domain>/<zid>/<nid>/<id>/<NN|MP|MS>/<enclave>/<namespace>/<node>
    /// [/<topic>/<type>/<hash>/<qos>]` for entity `id` of type `M` (ignored for a node).
    pub fn liveliness<M: RosMsg>(
        &self,
        domain: u32,
        distro: Distro,
        id: u32,
        entity: Entity<'_>,
    ) -> String {
        let (kind, topic) = match entity {
            Entity::Node => ("NN", None),
            Entity::Publisher { topic } => ("MP", Some(topic)),
            Entity::Subscription { topic } => ("MS", Some(topic)),
        };
        let mut key = format!(
            "@ros2_lv/{domain}/{}/{}/{id}/{kind}/{}/{}/{}",
            self.zid,
            self.nid,
            mangle(&self.enclave),
            mangle(&self.namespace),
            mangle(&self.name)
        );
        if let Some(topic) = topic {
            let fq = if topic.starts_with('/') {
                topic.to_string()
            } else {
                format!("/{topic}")
            };
            key.push_str(&format!(
                "/{}/{}/{}/{DEFAULT_QOS}",
                mangle(&fq),
                dds_type_name(M::NAME),
                distro.type_hash::<M>()
            ));
        }
        key
    }
}

/// The GID rmw_zenoh gives an entity: the XXH3 128-bit hash of its liveliness key, low 64
/// bits then high 64 bits, little-endian.
pub fn gid_of(liveliness_key: &str) -> [u8; 16] {
    let h = xxhash_rust::xxh3::xxh3_128(liveliness_key.as_bytes());
    let mut gid = [0u8; 16];
    gid[..8].copy_from_slice(&(h as u64).to_le_bytes());
    gid[8..].copy_from_slice(&((h >> 64) as u64).to_le_bytes());
    gid
}

/// rmw_zenoh's attachment of a publication: zenoh-ext serialisation of
/// `(i64 sequence_number, i64 source_timestamp_ns, [u8; 16] source_gid)`: 8 + 8 bytes
/// little-endian, then the GID as a sequence (LEB128 length 16, then the bytes): 33 bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Attachment {
    pub sequence_number: i64,
    pub source_timestamp_ns: i64,
    pub source_gid: [u8; 16],
}

/// Size of an [`Attachment`] on the wire.
pub const ATTACHMENT_BYTES: usize = 33;

impl Attachment {
    pub fn encode(&self) -> [u8; ATTACHMENT_BYTES] {
        let mut b = [0u8; ATTACHMENT_BYTES];
        b[..8].copy_from_slice(&self.sequence_number.to_le_bytes());
        b[8..16].copy_from_slice(&self.source_timestamp_ns.to_le_bytes());
        b[16] = 16;
        b[17..].copy_from_slice(&self.source_gid);
        b
    }

    pub fn decode(b: &[u8]) -> Option<Self> {
        if b.len() != ATTACHMENT_BYTES || b[16] != 16 {
            return None;
        }
        let mut gid = [0u8; 16];
        gid.copy_from_slice(&b[17..]);
        Some(Self {
            sequence_number: i64::from_le_bytes(b[..8].try_into().ok()?),
            source_timestamp_ns: i64::from_le_bytes(b[8..16].try_into().ok()?),
            source_gid: gid,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::msg::{Odometry, Twist};

    #[test]
    fn bridge_keys_are_topic_names() {
        let plain = Ros2Style::Bridge { namespace: None };
        assert_eq!(plain.key::<Twist>("/cmd_vel"), "cmd_vel");
        assert_eq!(plain.key::<Odometry>("odom"), "odom");
        let ns = Ros2Style::Bridge {
            namespace: Some("/robot1".into()),
        };
        assert_eq!(ns.key::<Twist>("cmd_vel"), "robot1/cmd_vel");
        assert!(!plain.attaches());
        assert!(check_topic("/robot1/cmd_vel").is_ok());
        for bad in ["", "/", "a//b", "cmd vel", "a/*", "9x", "a/$b"] {
            assert!(check_topic(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn attachments_are_33_bytes_and_round_trip() {
        let a = Attachment {
            sequence_number: 5,
            source_timestamp_ns: 1_700_000_000_123_456_789,
            source_gid: [7; 16],
        };
        let b = a.encode();
        assert_eq!(b.len(), 33);
        assert_eq!(Attachment::decode(&b), Some(a));
        assert_eq!(Attachment::decode(&b[..32]), None);
    }
}
