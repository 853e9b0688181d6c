//! Tracked people from the three message types (`--people-format`), as the policy sees them.

use crate::msg::{
    self, AgentState, AgentStates, CdrError, Header, People, Person, Point, Pose,
    PoseWithCovariance, TrackedPerson, TrackedPersons, Twist, TwistWithCovariance,
};
use sim::Vec2;

/// Which message the people topic carries.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum PeopleFormat {
    /// `people_msgs/msg/People` (default).
    #[default]
    People,
    /// `spencer_tracking_msgs/msg/TrackedPersons`.
    Spencer,
    /// `pedsim_msgs/msg/AgentStates`.
    Pedsim,
}

impl PeopleFormat {
    pub fn name(self) -> &'static str {
        match self {
            PeopleFormat::People => "people",
            PeopleFormat::Spencer => "spencer",
            PeopleFormat::Pedsim => "pedsim",
        }
    }
}

impl std::str::FromStr for PeopleFormat {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "people" => Ok(Self::People),
            "spencer" => Ok(Self::Spencer),
            "pedsim" => Ok(Self::Pedsim),
            _ => Err(format!("{s:?}: not people, spencer or pedsim")),
        }
    }
}

/// One tracked person in the people message's frame. What the message does not say is `None`
/// and filled in by the served policy (`ServedPolicy::scenario`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PersonObs {
    pub position: Vec2,
    pub velocity: Vec2,
    pub radius_m: Option<f64>,
    pub goal: Option<Vec2>,
    pub v_pref_mps: Option<f64>,
    pub standing: Option<bool>,
}

impl PersonObs {
    /// A person as a tracker reports it: position and velocity, nothing else known.
    pub fn tracked(position: Vec2, velocity: Vec2) -> PersonObs {
        PersonObs {
            position,
            velocity,
            radius_m: None,
            goal: None,
            v_pref_mps: None,
            standing: None,
        }
    }

    /// A simulated human as a tracker that knows everything would report it.
    pub fn of_human(h: &sim::HumanState) -> PersonObs {
        PersonObs {
            position: h.position,
            velocity: h.velocity,
            radius_m: Some(h.radius_m),
            goal: Some(h.goal),
            v_pref_mps: Some(h.v_pref_mps),
            standing: Some(h.standing),
        }
    }
}

/// A decoded people message.
#[derive(Debug, Clone, PartialEq)]
pub struct PeopleObs {
    pub header: Header,
    pub people: Vec<PersonObs>,
}

/// `people_msgs/Person` tags fsrl reads and writes (values as Rust prints an f64, which reads
/// back to the same bits): `radius_m`, `goal_x_m`, `goal_y_m`, `v_pref_mps`, `standing`
/// (`true`/`false`). A tracker sends none of them; the robot stand-in sends them all.
pub const TAG_RADIUS: &str = "radius_m";
pub const TAG_GOAL_X: &str = "goal_x_m";
pub const TAG_GOAL_Y: &str = "goal_y_m";
pub const TAG_V_PREF: &str = "v_pref_mps";
pub const TAG_STANDING: &str = "standing";

fn xy(p: &Point) -> Vec2 {
    Vec2::new(p.x, p.y)
}

fn finite(v: Vec2) -> bool {
    v.x.is_finite() && v.y.is_finite()
}

/// Why a people message cannot be used.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PeopleError {
    #[error(transparent)]
    Cdr(#[from] CdrError),
    #[error("person {0}: {1}")]
    Invalid(usize, String),
}

fn person_from_tags(i: usize, p: &Person) -> Result<PersonObs, PeopleError> {
    let mut out = PersonObs::tracked(xy(&p.position), xy(&p.velocity));
    let num = |v: &str, what: &str| -> Result<f64, PeopleError> {
        v.parse::<f64>()
            .ok()
            .filter(|x| x.is_finite())
            .ok_or_else(|| PeopleError::Invalid(i, format!("tag {what} = {v:?} is not a number")))
    };
    let (mut gx, mut gy) = (None, None);
    for (name, value) in p.tagnames.iter().zip(&p.tags) {
        match name.as_str() {
            TAG_RADIUS => out.radius_m = Some(num(value, name)?),
            TAG_GOAL_X => gx = Some(num(value, name)?),
            TAG_GOAL_Y => gy = Some(num(value, name)?),
            TAG_V_PREF => out.v_pref_mps = Some(num(value, name)?),
            TAG_STANDING => out.standing = Some(value == "true"),
            _ => {}
        }
    }
    if let (Some(x), Some(y)) = (gx, gy) {
        out.goal = Some(Vec2::new(x, y));
    }
    Ok(out)
}

/// The `people_msgs/Person` of a person with every tag fsrl reads.
pub fn person_with_tags(name: String, p: &PersonObs) -> Person {
    let mut tagnames = Vec::new();
    let mut tags = Vec::new();
    let mut tag = |n: &str, v: String| {
        tagnames.push(n.to_string());
        tags.push(v);
    };
    if let Some(r) = p.radius_m {
        tag(TAG_RADIUS, r.to_string());
    }
    if let Some(g) = p.goal {
        tag(TAG_GOAL_X, g.x.to_string());
        tag(TAG_GOAL_Y, g.y.to_string());
    }
    if let Some(v) = p.v_pref_mps {
        tag(TAG_V_PREF, v.to_string());
    }
    if let Some(s) = p.standing {
        tag(TAG_STANDING, s.to_string());
    }
    Person {
        name,
        position: Point {
            x: p.position.x,
            y: p.position.y,
            z: 0.0,
        },
        velocity: Point {
            x: p.velocity.x,
            y: p.velocity.y,
            z: 0.0,
        },
        reliability: 1.0,
        tagnames,
        tags,
    }
}

/// The people message of `format` for `people` (the inverse of [`decode`]): `people_msgs/People`
/// with every tag fsrl reads ([`person_with_tags`]); spencer's `TrackedPersons` and pedsim's
/// `AgentStates` with what those messages hold, positions and velocities (pedsim's social state
/// `standing` or `individual_moving` as well, which [`decode`] does not read), so the reader
/// fills in the rest as for any tracker. Person `i` is track or agent `i`.
pub fn encode(
    format: PeopleFormat,
    header: &Header,
    people: &[PersonObs],
) -> Result<Vec<u8>, CdrError> {
    let point = |v: Vec2| Point {
        x: v.x,
        y: v.y,
        z: 0.0,
    };
    let pose = |p: &PersonObs| Pose {
        position: point(p.position),
        ..Pose::default()
    };
    let twist = |p: &PersonObs| Twist {
        linear: point(p.velocity),
        ..Twist::default()
    };
    match format {
        PeopleFormat::People => msg::encode(&People {
            header: header.clone(),
            people: people
                .iter()
                .enumerate()
                .map(|(i, p)| person_with_tags(i.to_string(), p))
                .collect(),
        }),
        PeopleFormat::Spencer => msg::encode(&TrackedPersons {
            header: header.clone(),
            tracks: people
                .iter()
                .zip(0..)
                .map(|(p, i)| TrackedPerson {
                    track_id: i,
                    is_matched: true,
                    detection_id: i,
                    pose: PoseWithCovariance {
                        pose: pose(p),
                        ..PoseWithCovariance::default()
                    },
                    twist: TwistWithCovariance {
                        twist: twist(p),
                        ..TwistWithCovariance::default()
                    },
                    ..TrackedPerson::default()
                })
                .collect(),
        }),
        PeopleFormat::Pedsim => msg::encode(&AgentStates {
            header: header.clone(),
            agent_states: people
                .iter()
                .zip(0..)
                .map(|(p, i)| AgentState {
                    header: header.clone(),
                    id: i,
                    social_state: if p.standing == Some(true) {
                        "standing"
                    } else {
                        "individual_moving"
                    }
                    .into(),
                    pose: pose(p),
                    twist: twist(p),
                    ..AgentState::default()
                })
                .collect(),
        }),
    }
}

/// Decodes a people message of `format`; positions and velocities must be finite, radii and
/// speeds positive.
pub fn decode(format: PeopleFormat, bytes: &[u8]) -> Result<PeopleObs, PeopleError> {
    let (header, people) = match format {
        PeopleFormat::People => {
            let m: People = msg::decode(bytes)?;
            let people = m
                .people
                .iter()
                .enumerate()
                .map(|(i, p)| person_from_tags(i, p))
                .collect::<Result<Vec<_>, _>>()?;
            (m.header, people)
        }
        PeopleFormat::Spencer => {
            let m: TrackedPersons = msg::decode(bytes)?;
            let people = m
                .tracks
                .iter()
                .map(|t| PersonObs::tracked(xy(&t.pose.pose.position), xy(&t.twist.twist.linear)))
                .collect();
            (m.header, people)
        }
        PeopleFormat::Pedsim => {
            let m: AgentStates = msg::decode(bytes)?;
            let people = m
                .agent_states
                .iter()
                .map(|a| PersonObs::tracked(xy(&a.pose.position), xy(&a.twist.linear)))
                .collect();
            (m.header, people)
        }
    };
    for (i, p) in people.iter().enumerate() {
        if !finite(p.position) || !finite(p.velocity) || p.goal.is_some_and(|g| !finite(g)) {
            return Err(PeopleError::Invalid(i, "a value is not finite".into()));
        }
        if p.radius_m.is_some_and(|r| r <= 0.0) || p.v_pref_mps.is_some_and(|v| v <= 0.0) {
            return Err(PeopleError::Invalid(
                i,
                "radius and preferred speed must be positive".into(),
            ));
        }
    }
    Ok(PeopleObs { header, people })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_three_formats_give_positions_and_velocities() {
        let obs = PersonObs {
            position: Vec2::new(1.5, -2.0),
            velocity: Vec2::new(0.1, 0.7),
            radius_m: Some(0.3),
            goal: Some(Vec2::new(-1.0 / 3.0, 4.0)),
            v_pref_mps: Some(1.0),
            standing: Some(false),
        };
        let header = Header {
            frame_id: "odom".into(),
            ..Header::default()
        };
        let people = People {
            header: header.clone(),
            people: vec![person_with_tags("0".into(), &obs)],
        };
        let back = decode(PeopleFormat::People, &msg::encode(&people).unwrap()).unwrap();
        assert_eq!(back.people, vec![obs]);
        assert_eq!(back.header, header);

        let pose = PoseWithCovariance {
            pose: Pose {
                position: Point {
                    x: 1.5,
                    y: -2.0,
                    z: 0.0,
                },
                ..Pose::default()
            },
            ..Default::default()
        };
        let twist = Twist {
            linear: Point {
                x: 0.1,
                y: 0.7,
                z: 0.0,
            },
            ..Twist::default()
        };
        let bare = PersonObs::tracked(obs.position, obs.velocity);
        let spencer = TrackedPersons {
            header: header.clone(),
            tracks: vec![TrackedPerson {
                track_id: 4,
                pose,
                twist: TwistWithCovariance {
                    twist,
                    ..Default::default()
                },
                ..Default::default()
            }],
        };
        let back = decode(PeopleFormat::Spencer, &msg::encode(&spencer).unwrap()).unwrap();
        assert_eq!(back.people, vec![bare]);
        let pedsim = AgentStates {
            header,
            agent_states: vec![AgentState {
                id: 1,
                pose: pose.pose,
                twist,
                social_state: "walking".into(),
                ..Default::default()
            }],
        };
        let back = decode(PeopleFormat::Pedsim, &msg::encode(&pedsim).unwrap()).unwrap();
        assert_eq!(back.people, vec![bare]);
        // A format mismatch is an error, not a panic.
        assert!(decode(PeopleFormat::Pedsim, &msg::encode(&people).unwrap()).is_err());
    }

    #[test]
    fn encode_is_decode_s_inverse_for_what_each_format_holds() {
        let header = Header {
            frame_id: "odom".into(),
            ..Header::default()
        };
        let people = [
            PersonObs::of_human(&sim::HumanState {
                position: Vec2::new(1.5, -2.0),
                velocity: Vec2::new(0.1, -0.7),
                goal: Vec2::new(-1.0 / 3.0, 4.0),
                radius_m: 0.3,
                v_pref_mps: 1.0,
                standing: false,
            }),
            PersonObs::tracked(Vec2::new(-3.0, 0.25), Vec2::zeros()),
        ];
        for format in [
            PeopleFormat::People,
            PeopleFormat::Spencer,
            PeopleFormat::Pedsim,
        ] {
            let back = decode(format, &encode(format, &header, &people).unwrap()).unwrap();
            assert_eq!(back.header, header, "{format:?}");
            let want: Vec<PersonObs> = match format {
                PeopleFormat::People => people.to_vec(),
                _ => people
                    .iter()
                    .map(|p| PersonObs::tracked(p.position, p.velocity))
                    .collect(),
            };
            assert_eq!(back.people, want, "{format:?}");
        }
    }

    #[test]
    fn bad_tags_and_values_are_refused() {
        let mut p = person_with_tags(
            "x".into(),
            &PersonObs {
                position: Vec2::zeros(),
                velocity: Vec2::zeros(),
                radius_m: Some(0.3),
                goal: None,
                v_pref_mps: None,
                standing: None,
            },
        );
        p.tags[0] = "wide".into();
        let m = People {
            header: Header::default(),
            people: vec![p.clone()],
        };
        assert!(decode(PeopleFormat::People, &msg::encode(&m).unwrap()).is_err());
        p.tags[0] = "-1".into();
        let m = People {
            header: Header::default(),
            people: vec![p.clone()],
        };
        assert!(decode(PeopleFormat::People, &msg::encode(&m).unwrap()).is_err());
        p.tags[0] = "0.3".into();
        p.position.x = f64::INFINITY;
        let m = People {
            header: Header::default(),
            people: vec![p],
        };
        assert!(decode(PeopleFormat::People, &msg::encode(&m).unwrap()).is_err());
    }
}
