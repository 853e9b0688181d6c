//! ROS 2 interop checked against independent references:
//!
//! - every message type's CDR bytes against Python's `rosbags` (its own ROS 2 message
//!   definitions and CDR serialiser), both ways: rosbags writes the same bytes from the same
//!   fields, reads fsrl's bytes back to the same fields, and fsrl reads rosbags' bytes back to
//!   the same message; and the Jazzy type hashes fsrl puts in keys are rosbags' `hash_rihs01`;
//! - rmw_zenoh's keys, liveliness tokens and attachment against `fixtures/rmw_zenoh.json`,
//!   written from rmw_zenoh's sources (not from this crate);
//! - the publisher GID (XXH3-128 of the liveliness token, as rmw_zenoh derives it) against
//!   Python's `xxhash` (the reference C implementation), in the byte order of the attachment.
//!
//! Needs `python3` with `rosbags` and `xxhash` (tools/test.sh installs them into .venv/).

use std::io::Write;
use std::process::{Command, Stdio};

use serde::Serialize;
use serve::msg::{self, *};
use serve::ros2::{gid_of, Attachment, Distro, Entity, NodeId, Ros2Style};

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
    v.push(case(LaserScan {
        header: header(7, "base_scan"),
        angle_min: -std::f32::consts::PI,
        angle_max: std::f32::consts::PI - 0.5,
        angle_increment: 0.5,
        time_increment: 1e-4,
        scan_time: 0.1,
        range_min: 0.05,
        range_max: 8.0,
        ranges: (0..13).map(|i| 0.5 + i as f32 * 0.25).collect(),
        intensities: vec![],
    }));
    v.push(case(LaserScan::default()));
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

/// Runs `tests/fixtures/<script>` with `input` as JSON on stdin; its stdout as JSON.
fn python(script: &str, input: &impl Serialize) -> serde_json::Value {
    let path = format!("{}/tests/fixtures/{script}", env!("CARGO_MANIFEST_DIR"));
    let mut child = Command::new("python3")
        .arg(&path)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("python3 with `rosbags` and `xxhash` is required (tools/test.sh installs them)");
    child
        .stdin
        .take()
        .unwrap()
        .write_all(&serde_json::to_vec(input).unwrap())
        .unwrap();
    let out = child.wait_with_output().unwrap();
    assert!(
        out.status.success(),
        "{script} failed (python3 with `rosbags` and `xxhash` is required):\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

#[test]
fn cdr_bytes_match_rosbags_both_ways_and_type_hashes_agree() {
    let cases = cases();
    let samples: Vec<&Sample> = cases.iter().map(|c| &c.sample).collect();
    let v = python("cdr_check.py", &samples);
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
        (LaserScan::NAME, LaserScan::JAZZY_HASH),
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

/// Liveliness keys whose GID is checked: tokens of every kind fsrl declares, in both distros,
/// with a real session id (32 hex digits) and topics of the lengths robots use, the fixture's
/// tokens, and strings of every length class XXH3 hashes differently (0, 1-3, 4-8, 9-16, 17-128,
/// 129-240 bytes and longer), since tokens cross those bounds with names and type hashes.
fn gid_keys() -> Vec<String> {
    let node = |namespace: &str, name: &str| NodeId {
        zid: "d6a4e1f0c3b2a1908f7e6d5c4b3a2910".into(),
        nid: 0,
        namespace: namespace.into(),
        name: name.into(),
        enclave: "/".into(),
    };
    let fsrl = node("/", "fsrl");
    let long = node("/warehouse/fleet_a", "crowd_navigation_policy_server");
    let mut keys = Vec::new();
    for distro in [Distro::Humble, Distro::Jazzy] {
        for domain in [0, 42] {
            keys.push(fsrl.liveliness::<Twist>(domain, distro, 0, Entity::Node));
            keys.push(fsrl.liveliness::<Twist>(
                domain,
                distro,
                1,
                Entity::Publisher { topic: "cmd_vel" },
            ));
            keys.push(fsrl.liveliness::<Odometry>(
                domain,
                distro,
                2,
                Entity::Subscription { topic: "/odom" },
            ));
            keys.push(fsrl.liveliness::<PoseStamped>(
                domain,
                distro,
                3,
                Entity::Subscription { topic: "goal_pose" },
            ));
            keys.push(fsrl.liveliness::<TrackedPersons>(
                domain,
                distro,
                4,
                Entity::Subscription {
                    topic: "/spencer/perception/tracked_persons",
                },
            ));
            keys.push(long.liveliness::<AgentStates>(
                domain,
                distro,
                17,
                Entity::Subscription {
                    topic: "/warehouse/fleet_a/pedsim_visualizer/simulated_agents_in_the_odometry_frame",
                },
            ));
        }
    }
    for t in fixture()["tokens"].as_array().unwrap() {
        keys.push(t["token"].as_str().unwrap().to_string());
    }
    for len in [
        0, 1, 3, 4, 8, 9, 16, 17, 64, 128, 129, 200, 240, 241, 500, 1100,
    ] {
        keys.push(
            (0..len)
                .map(|i| (b'!' + (i * 7 % 90) as u8) as char)
                .collect(),
        );
    }
    keys
}

#[test]
fn publisher_gids_are_xxh3_128_of_the_token_as_python_xxhash_computes_it() {
    let keys = gid_keys();
    let lengths: Vec<usize> = keys.iter().map(String::len).collect();
    assert!(
        lengths.iter().any(|&l| (129..=240).contains(&l)) && lengths.iter().any(|&l| l > 240),
        "tokens of every length class: {lengths:?}"
    );
    let v = python("gid_check.py", &keys);
    let theirs = v.as_array().unwrap();
    assert_eq!(theirs.len(), keys.len());
    for (key, want) in keys.iter().zip(theirs) {
        let want = unhex(want.as_str().unwrap());
        let gid = gid_of(key);
        assert_eq!(gid.to_vec(), want, "GID of {key:?}");
        // Where rmw_zenoh's subscribers read it: the attachment's last 16 bytes.
        let att = Attachment {
            sequence_number: 1,
            source_timestamp_ns: 0,
            source_gid: gid,
        };
        assert_eq!(&att.encode()[17..], &want[..], "{key:?}");
    }
}
