//! The ROS 2 messages `fsrl serve` speaks, as serde structs in their IDL field order, and their
//! CDR form as it travels in ROS 2 (a 4-byte encapsulation header, then plain CDR; little-endian
//! written, both byte orders read) through `cdr-encoding`.
//!
//! Standard: `nav_msgs/msg/Odometry`, `geometry_msgs/msg/PoseStamped`, `geometry_msgs/msg/Twist`,
//! `sensor_msgs/msg/LaserScan`.
//! People: `people_msgs/msg/People` (wg-perception/people, ROS 2 branch),
//! `spencer_tracking_msgs/msg/TrackedPersons` and `pedsim_msgs/msg/AgentStates` (srl-freiburg
//! pedsim_ros; forks that add fields do not decode). The definitions are in
//! `serve/tests/fixtures/msg_defs.py`, which the byte checks against Python's `rosbags` use.

use serde::de::DeserializeOwned;
use serde::{Deserialize, Deserializer, Serialize, Serializer};

/// The encapsulation header of little-endian plain CDR (`CDR_LE`, options 0).
pub const CDR_LE_HEADER: [u8; 4] = [0x00, 0x01, 0x00, 0x00];
/// Largest message decoded (a people message of thousands of tracks fits).
pub const MAX_MESSAGE_BYTES: usize = 4 << 20;

/// A ROS 2 message type.
pub trait RosMsg: Serialize + DeserializeOwned {
    /// `package/msg/Name`.
    const NAME: &'static str;
    /// The type hash ROS 2 Jazzy computes (`RIHS01_` + SHA-256 of the type description;
    /// checked against `rosbags`' `hash_rihs01` in `serve/tests/rosbags.rs`).
    const JAZZY_HASH: &'static str;
}

/// `package::msg::dds_::Name_`: the DDS name of a `package/msg/Name` type, as rmw_zenoh puts
/// it in keys.
pub fn dds_type_name(name: &str) -> String {
    let mut parts: Vec<&str> = name.split('/').collect();
    let last = parts.pop().unwrap_or_default();
    let mut s = parts.join("::");
    s.push_str("::dds_::");
    s.push_str(last);
    s.push('_');
    s
}

/// Why bytes are not a message.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CdrError {
    #[error("{0} bytes: shorter than the 4-byte encapsulation header")]
    Short(usize),
    #[error("{0} bytes: more than the {MAX_MESSAGE_BYTES} accepted")]
    TooLarge(usize),
    #[error(
        "encapsulation {0:#04x}{1:02x}: not plain CDR (0x0000 big-endian, 0x0001 little-endian)"
    )]
    Encapsulation(u8, u8),
    #[error("{0}")]
    Decode(String),
    #[error("{0} bytes left over after the message")]
    Trailing(usize),
    #[error("cannot encode: {0}")]
    Encode(String),
}

/// The CDR bytes of `m` with the little-endian encapsulation header.
pub fn encode<M: RosMsg>(m: &M) -> Result<Vec<u8>, CdrError> {
    let body = cdr_encoding::to_vec::<M, byteorder::LittleEndian>(m)
        .map_err(|e| CdrError::Encode(e.to_string()))?;
    let mut out = Vec::with_capacity(4 + body.len());
    out.extend_from_slice(&CDR_LE_HEADER);
    out.extend_from_slice(&body);
    Ok(out)
}

/// Decodes a message with its encapsulation header. Up to 3 bytes after the message are
/// accepted (alignment padding some writers add); more is an error.
pub fn decode<M: RosMsg>(bytes: &[u8]) -> Result<M, CdrError> {
    if bytes.len() < 4 {
        return Err(CdrError::Short(bytes.len()));
    }
    if bytes.len() > MAX_MESSAGE_BYTES {
        return Err(CdrError::TooLarge(bytes.len()));
    }
    let body = &bytes[4..];
    let (m, used) = match (bytes[0], bytes[1]) {
        (0x00, 0x01) => cdr_encoding::from_bytes::<M, byteorder::LittleEndian>(body),
        (0x00, 0x00) => cdr_encoding::from_bytes::<M, byteorder::BigEndian>(body),
        (a, b) => return Err(CdrError::Encapsulation(a, b)),
    }
    .map_err(|e| CdrError::Decode(e.to_string()))?;
    let left = body.len().saturating_sub(used);
    if left > 3 {
        return Err(CdrError::Trailing(left));
    }
    Ok(m)
}

/// `builtin_interfaces/msg/Time`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct Time {
    pub sec: i32,
    pub nanosec: u32,
}

impl Time {
    /// The time `t_s` seconds after the epoch (negative and huge values saturate).
    pub fn from_secs_f64(t_s: f64) -> Self {
        let t = if t_s.is_finite() { t_s.max(0.0) } else { 0.0 };
        let sec = t.floor().min(i32::MAX as f64);
        let nanosec = (((t - sec) * 1e9).round() as u32).min(999_999_999);
        Self {
            sec: sec as i32,
            nanosec,
        }
    }

    pub fn as_secs_f64(self) -> f64 {
        self.sec as f64 + self.nanosec as f64 * 1e-9
    }

    pub fn is_zero(self) -> bool {
        self.sec == 0 && self.nanosec == 0
    }
}

/// `builtin_interfaces/msg/Duration`.
pub type Duration = Time;

/// `std_msgs/msg/Header`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct Header {
    pub stamp: Time,
    pub frame_id: String,
}

/// `geometry_msgs/msg/Point`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Point {
    pub x: f64,
    pub y: f64,
    pub z: f64,
}

/// `geometry_msgs/msg/Vector3`.
pub type Vector3 = Point;

/// `geometry_msgs/msg/Quaternion`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Quaternion {
    pub x: f64,
    pub y: f64,
    pub z: f64,
    pub w: f64,
}

impl Default for Quaternion {
    fn default() -> Self {
        Self::from_yaw(0.0)
    }
}

impl Quaternion {
    /// The rotation by `yaw_rad` about z.
    pub fn from_yaw(yaw_rad: f64) -> Self {
        let h = 0.5 * yaw_rad;
        Self {
            x: 0.0,
            y: 0.0,
            z: h.sin(),
            w: h.cos(),
        }
    }

    /// The rotation's yaw (about z), in (−π, π].
    pub fn yaw(&self) -> f64 {
        (2.0 * (self.w * self.z + self.x * self.y))
            .atan2(1.0 - 2.0 * (self.y * self.y + self.z * self.z))
    }
}

/// `geometry_msgs/msg/Pose`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Pose {
    pub position: Point,
    pub orientation: Quaternion,
}

/// `float64[36]`, a 6×6 covariance (serde derives arrays up to 32 only).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Covariance(pub [f64; 36]);

impl Default for Covariance {
    fn default() -> Self {
        Self([0.0; 36])
    }
}

impl Serialize for Covariance {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeTuple;
        let mut t = s.serialize_tuple(36)?;
        for v in &self.0 {
            t.serialize_element(v)?;
        }
        t.end()
    }
}

impl<'de> Deserialize<'de> for Covariance {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl<'de> serde::de::Visitor<'de> for V {
            type Value = Covariance;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("36 float64")
            }
            fn visit_seq<A: serde::de::SeqAccess<'de>>(
                self,
                mut a: A,
            ) -> Result<Covariance, A::Error> {
                let mut out = [0.0; 36];
                for (i, slot) in out.iter_mut().enumerate() {
                    *slot = a
                        .next_element()?
                        .ok_or_else(|| serde::de::Error::invalid_length(i, &self))?;
                }
                Ok(Covariance(out))
            }
        }
        d.deserialize_tuple(36, V)
    }
}

/// `geometry_msgs/msg/PoseWithCovariance`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct PoseWithCovariance {
    pub pose: Pose,
    pub covariance: Covariance,
}

/// `geometry_msgs/msg/Twist`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Twist {
    pub linear: Vector3,
    pub angular: Vector3,
}

impl Twist {
    pub const ZERO: Twist = Twist {
        linear: Point {
            x: 0.0,
            y: 0.0,
            z: 0.0,
        },
        angular: Point {
            x: 0.0,
            y: 0.0,
            z: 0.0,
        },
    };
}

/// `geometry_msgs/msg/TwistWithCovariance`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct TwistWithCovariance {
    pub twist: Twist,
    pub covariance: Covariance,
}

/// `nav_msgs/msg/Odometry`: pose in `header.frame_id`, twist in `child_frame_id` (the body).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct Odometry {
    pub header: Header,
    pub child_frame_id: String,
    pub pose: PoseWithCovariance,
    pub twist: TwistWithCovariance,
}

/// `geometry_msgs/msg/PoseStamped`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct PoseStamped {
    pub header: Header,
    pub pose: Pose,
}

/// `people_msgs/msg/Person`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct Person {
    pub name: String,
    pub position: Point,
    pub velocity: Point,
    pub reliability: f64,
    pub tagnames: Vec<String>,
    pub tags: Vec<String>,
}

/// `people_msgs/msg/People`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct People {
    pub header: Header,
    pub people: Vec<Person>,
}

/// `spencer_tracking_msgs/msg/TrackedPerson`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct TrackedPerson {
    pub track_id: u64,
    pub is_occluded: bool,
    pub is_matched: bool,
    pub detection_id: u64,
    pub age: Duration,
    pub pose: PoseWithCovariance,
    pub twist: TwistWithCovariance,
}

/// `spencer_tracking_msgs/msg/TrackedPersons`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct TrackedPersons {
    pub header: Header,
    pub tracks: Vec<TrackedPerson>,
}

/// `pedsim_msgs/msg/AgentForce`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct AgentForce {
    pub desired_force: Vector3,
    pub obstacle_force: Vector3,
    pub social_force: Vector3,
    pub group_coherence_force: Vector3,
    pub group_gaze_force: Vector3,
    pub group_repulsion_force: Vector3,
    pub random_force: Vector3,
}

/// `pedsim_msgs/msg/AgentState`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct AgentState {
    pub header: Header,
    pub id: u64,
    #[serde(rename = "type")]
    pub kind: u16,
    pub social_state: String,
    pub pose: Pose,
    pub twist: Twist,
    pub forces: AgentForce,
}

/// `pedsim_msgs/msg/AgentStates`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct AgentStates {
    pub header: Header,
    pub agent_states: Vec<AgentState>,
}

/// `sensor_msgs/msg/LaserScan`: beam `i` at `angle_min + i·angle_increment` in the frame of
/// `header.frame_id` (the robot's base frame for `fsrl serve --scan`), ranges in metres (REP
/// 117: `+inf` no return, `-inf` too near, NaN an erroneous reading).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct LaserScan {
    pub header: Header,
    pub angle_min: f32,
    pub angle_max: f32,
    pub angle_increment: f32,
    pub time_increment: f32,
    pub scan_time: f32,
    pub range_min: f32,
    pub range_max: f32,
    pub ranges: Vec<f32>,
    pub intensities: Vec<f32>,
}

macro_rules! ros_msg {
    ($t:ty, $name:literal, $hash:literal) => {
        impl RosMsg for $t {
            const NAME: &'static str = $name;
            const JAZZY_HASH: &'static str = $hash;
        }
    };
}

ros_msg!(
    Twist,
    "geometry_msgs/msg/Twist",
    "RIHS01_9c45bf16fe0983d80e3cfe750d6835843d265a9a6c46bd2e609fcddde6fb8d2a"
);
ros_msg!(
    Odometry,
    "nav_msgs/msg/Odometry",
    "RIHS01_3cc97dc7fb7502f8714462c526d369e35b603cfc34d946e3f2eda2766dfec6e0"
);
ros_msg!(
    PoseStamped,
    "geometry_msgs/msg/PoseStamped",
    "RIHS01_10f3786d7d40fd2b54367835614bff85d4ad3b5dab62bf8bca0cc232d73b4cd8"
);
ros_msg!(
    People,
    "people_msgs/msg/People",
    "RIHS01_9ea98a5e58f833a9532957bca23a6b8006a12885d5a16c8ca41dd901d10c33b6"
);
ros_msg!(
    TrackedPersons,
    "spencer_tracking_msgs/msg/TrackedPersons",
    "RIHS01_ff1e8664006cb714514f28e537ddf9b82d898b47909897eed6f5c172deb9378b"
);
ros_msg!(
    LaserScan,
    "sensor_msgs/msg/LaserScan",
    "RIHS01_64c191398013af96509d518dac71d5164f9382553fce5c1f8cca5be7924bd828"
);
ros_msg!(
    AgentStates,
    "pedsim_msgs/msg/AgentStates",
    "RIHS01_2ee2abbfb68a74b19e52f68b0780c9bb857cfc22d2da74cc9fb2a798b3a68846"
);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn twist_bytes_are_the_header_and_six_doubles() {
        let t = Twist {
            linear: Point {
                x: 1.0,
                y: 0.0,
                z: 0.0,
            },
            angular: Point {
                x: 0.0,
                y: 0.0,
                z: -0.5,
            },
        };
        let b = encode(&t).unwrap();
        assert_eq!(b.len(), 4 + 48);
        assert_eq!(&b[..4], &CDR_LE_HEADER);
        assert_eq!(&b[4..12], &1.0f64.to_le_bytes());
        assert_eq!(&b[44..52], &(-0.5f64).to_le_bytes());
        assert_eq!(decode::<Twist>(&b).unwrap(), t);
    }

    #[test]
    fn strings_are_length_prefixed_null_terminated_and_padded() {
        let p = PoseStamped {
            header: Header {
                stamp: Time { sec: 3, nanosec: 7 },
                frame_id: "map".into(),
            },
            pose: Pose::default(),
        };
        let b = encode(&p).unwrap();
        // stamp (8) + length 4 + "map\0" (4) = 16, already 8-aligned for the doubles.
        assert_eq!(&b[4 + 8..4 + 12], &4u32.to_le_bytes());
        assert_eq!(&b[4 + 12..4 + 16], b"map\0");
        assert_eq!(b.len(), 4 + 16 + 56);
        assert_eq!(decode::<PoseStamped>(&b).unwrap(), p);
        let odd = PoseStamped {
            header: Header {
                stamp: Time::default(),
                frame_id: "odom".into(),
            },
            ..p
        };
        // "odom\0" is 5 bytes: 8 + 4 + 5 = 17, padded to 24 before the first double.
        let b = encode(&odd).unwrap();
        assert_eq!(b.len(), 4 + 24 + 56);
        assert_eq!(decode::<PoseStamped>(&b).unwrap(), odd);
    }

    #[test]
    fn bad_bytes_are_errors_never_panics() {
        let good = encode(&People {
            header: Header::default(),
            people: vec![Person {
                name: "a".into(),
                tagnames: vec!["radius_m".into()],
                tags: vec!["0.3".into()],
                ..Person::default()
            }],
        })
        .unwrap();
        assert!(decode::<People>(&good).is_ok());
        assert!(matches!(decode::<People>(&[0, 1]), Err(CdrError::Short(2))));
        assert!(matches!(
            decode::<People>(&[7, 7, 0, 0, 1, 2, 3]),
            Err(CdrError::Encapsulation(7, 7))
        ));
        // Every truncation and every single-byte corruption decodes or fails, never panics.
        for n in 0..good.len() {
            let _ = decode::<People>(&good[..n]);
        }
        for i in 0..good.len() {
            for v in [0x00, 0xff, 0x80, 0x7f] {
                let mut b = good.clone();
                b[i] = v;
                let _ = decode::<People>(&b);
            }
        }
        // A huge sequence length does not allocate its claim.
        let mut b = encode(&People::default()).unwrap();
        let n = b.len();
        b[n - 4..].copy_from_slice(&u32::MAX.to_le_bytes());
        assert!(decode::<People>(&b).is_err());
        let mut long = good.clone();
        long.extend_from_slice(&[0; 8]);
        assert!(matches!(
            decode::<People>(&long),
            Err(CdrError::Trailing(8))
        ));
    }

    #[test]
    fn yaw_survives_the_quaternion_within_rounding() {
        for i in -314..=314 {
            let yaw = i as f64 * 0.01;
            let back = Quaternion::from_yaw(yaw).yaw();
            assert!((back - yaw).abs() < 1e-14, "{yaw} {back}");
        }
        assert_eq!(
            dds_type_name("geometry_msgs/msg/Twist"),
            "geometry_msgs::msg::dds_::Twist_"
        );
    }
}
