//! ROS 2 interop checked against independent references:
//!
//! - every message type's CDR bytes against Python's `rosbags` (its own ROS 2 message
//!   definitions and CDR serialiser), both ways: rosbags writes the same bytes from the same
//!   fields, reads fsrl's bytes back to the same fields, and fsrl reads rosbags' bytes back to
//!   the same message; and the Jazzy type hashes fsrl puts in keys are rosbags' `hash_rihs01`;
//! - rmw_zenoh's keys, liveliness tokens and attachment against `fixtures/rmw_zenoh.json`,
//!   written from rmw_zenoh's sources (not from this crate).
//!
//! Needs `python3` with `rosbags` (tools/test.sh installs it into .venv/).

use std::io::Write;
use std::process::{Command, Stdio};

use serde::Serialize;
use serve::msg::{self, *};
use serve::ros2::{Attachment, Distro, Entity, NodeId, Ros2Style};

#[derive(Serialize)]
struct Sample {
    r#type: &'static str,
    fields: serde_json::Value,
    cdr: String,
}

fn hex(b: &[u8]) -> String {
    b.iter().map(|x| format!("{x:02x}")).collect()
}

fn unhex(s: &str) -> Vec<u8> {
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
        .collect()
}

/// Checks that bytes decode back to the sample's message.
type Check = Box<dyn Fn(&[u8])>;

/// A sample and a check that bytes decode back to `m`.
struct Case {
    sample: Sample,
    check: Check,
}

fn case<M: RosMsg + PartialEq + std::fmt::Debug + 'static>(m: M) -> Case {
    let cdr = msg::encode(&m).unwrap();
    let fields = serde_json::to_value(&m).unwrap();
    // serde_json writes the Covariance tuples as arrays, as rosbags wants them.
    Case {
        sample: Sample {
            r#type: M::NAME,
            fields,
            cdr: hex(&cdr),
        },
        check: Box::new(move |b| assert_eq!(msg::decode::<M>(b).unwrap(), m, "{}", M::NAME)),
    }
}

fn header(sec: i32, frame: &str) -> Header {
    Header {
        stamp: Time {
            sec,
            nanosec: 250_000_000,
        },
        frame_id: frame.into(),
    }
}

fn p(x: f64, y: f64, z: f64) -> Point {
    Point { x, y, z }
}

fn cov(seed: f64) -> Covariance {
    let mut c = [0.0; 36];
    for (i, v) in c.iter_mut().enumerate() {
        *v = seed * i as f64 - 0.5;
    }
    Covariance(c)
}

fn cases() -> Vec<Case> {
    let pose = Pose {
        position: p(1.25, -4.0, 0.0),
        orientation: Quaternion::from_yaw(0.7),
    };
    let twist = Twist {
        linear: p(0.9, 0.0, 0.0),
        angular: p(0.0, 0.0, -0.31),
    };
    let mut v = vec![
        case(twist),
        case(Twist::ZERO),
        case(PoseStamped {
            header: header(1000, "odom"),
            pose,
        }),
        case(PoseStamped {
            header: header(0, ""),
            pose: Pose::default(),
        }),
    ];
    // Frame names of every length mod 8, so every padding before the doubles is exercised.
    for frame in [
        "o",
        "od",
        "odo",
        "odom",
        "odom_",
        "odom_a",
        "odom_ab",
        "map_long_",
    ] {
        v.push(case(Odometry {
            header: header(12, frame),
            child_frame_id: format!("base_{frame}"),
            pose: PoseWithCovariance {
                pose,
                covariance: cov(0.25),
            },
            twist: TwistWithCovariance {
                twist,
                covariance: cov(-1.5),
            },
        }));
    }
    let person = |name: &str, tags: usize| Person {
        name: name.into(),
        position: p(2.0, -1.0 / 3.0, 0.0),
        velocity: p(-0.5, 0.25, 0.0),
        reliability: 0.75,
        tagnames: (0..tags).map(|i| format!("tag{i}")).collect(),
        tags: (0..tags).map(|i| "x".repeat(i)).collect(),
    };
    v.push(case(People {
        header: header(3, "odom"),
        people: vec![],
    }));
    v.push(case(People {
        header: header(3, "odom"),
        people: vec![person("", 0), person("alice", 3), person("bob7", 5)],
    }));
    v.push(case(TrackedPersons {
        header: header(5, "odom"),
        tracks: vec![
            TrackedPerson {
                track_id: 42,
                is_occluded: true,
                is_matched: false,
                detection_id: u64::MAX - 3,
                age: Time { sec: 2, nanosec: 5 },
                pose: PoseWithCovariance {
                    pose,
                    covariance: cov(1.0),
                },
                twist: TwistWithCovariance {
                    twist,
                    covariance: cov(2.0),
                },
            },
            TrackedPerson::default(),
        ],
    }));
    v.push(case(AgentStates {
        header: header(9, "odom"),
        agent_states: vec![
            AgentState {
                header: header(9, "odom"),
                id: 3,
                kind: 1,
                social_state: "individual_moving".into(),
                pose,
                twist,
                forces: AgentForce {
                    desired_force: p(1.0, 2.0, 3.0),
                    random_force: p(-1.0, 0.5, 0.0),
                    ..AgentForce::default()
                },
            },
            AgentState::default(),
        ],
    }));
    v
}

#[test]
fn cdr_bytes_match_rosbags_both_ways_and_type_hashes_agree() {
    let cases = cases();
    let samples: Vec<&Sample> = cases.iter().map(|c| &c.sample).collect();
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/cdr_check.py");
    let mut child = Command::new("python3")
        .arg(script)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("python3 with the `rosbags` package is required (tools/test.sh installs it)");
    child
        .stdin
        .take()
        .unwrap()
        .write_all(&serde_json::to_vec(&samples).unwrap())
        .unwrap();
    let out = child.wait_with_output().unwrap();
    assert!(
        out.status.success(),
        "cdr_check.py failed (python3 with `rosbags` is required):\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let results = v["results"].as_array().unwrap();
    assert_eq!(results.len(), cases.len());
    for (c, r) in cases.iter().zip(results) {
        let t = c.sample.r#type;
        assert_eq!(
            r["cdr"].as_str().unwrap(),
            c.sample.cdr,
            "{t}: rosbags' bytes differ"
        );
        assert_eq!(r["same_bytes"], true, "{t}");
        assert_eq!(
            r["fields_back"], true,
            "{t}: rosbags reads fsrl's bytes differently"
        );
        (c.check)(&unhex(r["cdr"].as_str().unwrap()));
    }
    let hashes = &v["hashes"];
    for (name, ours) in [
        (Twist::NAME, Twist::JAZZY_HASH),
        (Odometry::NAME, Odometry::JAZZY_HASH),
        (PoseStamped::NAME, PoseStamped::JAZZY_HASH),
        (People::NAME, People::JAZZY_HASH),
        (TrackedPersons::NAME, TrackedPersons::JAZZY_HASH),
        (AgentStates::NAME, AgentStates::JAZZY_HASH),
    ] {
        assert_eq!(hashes[name].as_str(), Some(ours), "{name}");
    }
}

fn fixture() -> serde_json::Value {
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/fixtures/rmw_zenoh.json"
    ))
    .unwrap();
    serde_json::from_str(&text).unwrap()
}

fn key_for(style: &Ros2Style, ty: &str, topic: &str) -> String {
    match ty {
        "geometry_msgs/msg/Twist" => style.key::<Twist>(topic),
        "nav_msgs/msg/Odometry" => style.key::<Odometry>(topic),
        "geometry_msgs/msg/PoseStamped" => style.key::<PoseStamped>(topic),
        "people_msgs/msg/People" => style.key::<People>(topic),
        other => panic!("no type {other} in the fixture's list"),
    }
}

#[test]
fn rmw_zenoh_keys_tokens_and_attachments_match_the_fixtures() {
    let f = fixture();
    for k in f["keys"].as_array().unwrap() {
        let distro: Distro = k["distro"].as_str().unwrap().parse().unwrap();
        let style = Ros2Style::RmwZenoh {
            domain: k["domain"].as_u64().unwrap() as u32,
            distro,
        };
        let got = key_for(
            &style,
            k["type"].as_str().unwrap(),
            k["topic"].as_str().unwrap(),
        );
        assert_eq!(got, k["key"].as_str().unwrap());
    }
    for t in f["tokens"].as_array().unwrap() {
        let node = NodeId {
            zid: t["zid"].as_str().unwrap().into(),
            nid: t["nid"].as_u64().unwrap() as u32,
            namespace: t["namespace"].as_str().unwrap().into(),
            name: t["node"].as_str().unwrap().into(),
            enclave: "/".into(),
        };
        let distro: Distro = t["distro"].as_str().unwrap().parse().unwrap();
        let topic = t["topic"].as_str().unwrap_or_default();
        let entity = match t["entity"].as_str().unwrap() {
            "NN" => Entity::Node,
            "MP" => Entity::Publisher { topic },
            "MS" => Entity::Subscription { topic },
            e => panic!("{e}"),
        };
        let got = node.liveliness::<Twist>(
            t["domain"].as_u64().unwrap() as u32,
            distro,
            t["id"].as_u64().unwrap() as u32,
            entity,
        );
        assert_eq!(got, t["token"].as_str().unwrap());
    }
    for a in f["attachments"].as_array().unwrap() {
        let gid: [u8; 16] = unhex(a["source_gid"].as_str().unwrap()).try_into().unwrap();
        let att = Attachment {
            sequence_number: a["sequence_number"].as_i64().unwrap(),
            source_timestamp_ns: a["source_timestamp_ns"].as_i64().unwrap(),
            source_gid: gid,
        };
        let bytes = unhex(a["bytes"].as_str().unwrap());
        assert_eq!(bytes.len(), 33);
        assert_eq!(att.encode().to_vec(), bytes);
        assert_eq!(Attachment::decode(&bytes), Some(att));
    }
}
