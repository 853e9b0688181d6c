//! Which scalars a run's logs and live metrics give, under which tags. The step of every tag is
//! the RL episodes trained (an RL episode's line: its index + 1; a validation: the episodes it
//! was taken after), except the imitation loss, whose step is the imitation epochs done.
//! Names follow CleanRL's namespaces (`charts/`, `losses/`) and Sample Factory's (`perf/`,
//! `train/`).

use std::collections::{BTreeMap, VecDeque};

use proto::{Metrics, Role, SenderId};

/// The imitation loss per epoch (step: epochs done).
pub const IMITATION_LOSS: &str = "losses/imitation_loss";
/// The loss of the RL updates after an episode.
pub const TD_LOSS: &str = "losses/td_loss";
pub const EPISODIC_RETURN: &str = "charts/episodic_return";
pub const EPSILON: &str = "charts/epsilon";
/// Outcome rates over the last 100 RL episodes.
pub const SUCCESS_WINDOW: &str = "charts/success_rate_window";
pub const COLLISION_WINDOW: &str = "charts/collision_rate_window";
pub const TIMEOUT_WINDOW: &str = "charts/timeout_rate_window";
/// The validations (the learning curve).
pub const VAL_SUCCESS: &str = "validation/success_rate";
pub const VAL_COLLISION: &str = "validation/collision_rate";
pub const VAL_TIMEOUT: &str = "validation/timeout_rate";
pub const VAL_NAV_TIME: &str = "validation/nav_time_s";
pub const VAL_DISC: &str = "validation/discomfort";
pub const VAL_RETURN: &str = "validation/mean_return";
/// RL episodes per second taken in by the learner, all actors together.
pub const EPISODES_PER_S: &str = "perf/episodes_per_s";
/// The learner's updates per RL episode (its replay ratio).
pub const UPDATES_PER_EPISODE: &str = "train/updates_per_episode";
/// Policy lag (weights versions between an episode's policy and the learner's) over the
/// learner's window.
pub const POLICY_LAG_MEAN: &str = "train/policy_lag_mean";
pub const POLICY_LAG_MAX: &str = "train/policy_lag_max";
pub const ACTORS_ALIVE: &str = "perf/actors_alive";

/// RL episodes per second of one actor.
pub fn actor_episodes_per_s(actor: u32) -> String {
    format!("perf/episodes_per_s/actor_{actor}")
}

/// Episodes in the window of an episodes-per-second value.
pub const RATE_WINDOW: usize = 10;

/// The tags a distributed run's board takes from the learner's live metrics rather than from
/// the log (the log does not hold them).
pub fn is_live(tag: &str) -> bool {
    [
        UPDATES_PER_EPISODE,
        POLICY_LAG_MEAN,
        POLICY_LAG_MAX,
        ACTORS_ALIVE,
    ]
    .contains(&tag)
}

/// A tag's value at a step.
pub type Point = (String, i64, f64);

/// Which mode wrote the log.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Mode {
    /// One process: no lag (every episode is played with the newest weights), one actor, and
    /// the schedule's updates per episode; the log gives every tag.
    SingleProcess { updates_per_episode: f64 },
    /// Learner, actors and evaluator: the tags of [`is_live`] come from the learner's metrics.
    Distributed,
}

/// Episodes per second over a window of wall-clock times: (n − 1) / (last − first).
#[derive(Debug, Default, Clone)]
struct Rate(VecDeque<f64>);

impl Rate {
    fn push(&mut self, wall_s: f64) -> Option<f64> {
        if self.0.len() > RATE_WINDOW {
            self.0.pop_front();
        }
        self.0.push_back(wall_s);
        let (first, last) = (*self.0.front()?, *self.0.back()?);
        (self.0.len() >= 2 && last > first).then(|| (self.0.len() - 1) as f64 / (last - first))
    }
}

/// The points of a run's log lines (`metrics.jsonl`, `validation.jsonl`), read in order.
#[derive(Debug, Clone)]
pub struct LogMapper {
    mode: Mode,
    all: Rate,
    actors: BTreeMap<u32, Rate>,
}

impl LogMapper {
    pub fn new(mode: Mode) -> Self {
        LogMapper {
            mode,
            all: Rate::default(),
            actors: BTreeMap::new(),
        }
    }

    /// The points of one line (none for a line of no known phase).
    pub fn line(&mut self, v: &serde_json::Value) -> Vec<Point> {
        let num = |k: &str| v.get(k).and_then(|x| x.as_f64()).filter(|x| x.is_finite());
        let mut out = Vec::new();
        let mut put = |tag: &str, step: i64, value: Option<f64>| {
            if let Some(value) = value {
                out.push((tag.to_string(), step, value));
            }
        };
        match v.get("phase").and_then(|p| p.as_str()) {
            Some("imitation") => {
                if let Some(epoch) = v.get("epoch").and_then(|e| e.as_i64()) {
                    put(IMITATION_LOSS, epoch + 1, num("loss"));
                }
            }
            Some("validation") => {
                let Some(step) = v.get("episode").and_then(|e| e.as_i64()) else {
                    return out;
                };
                put(VAL_SUCCESS, step, num("success_rate"));
                put(VAL_COLLISION, step, num("collision_rate"));
                put(VAL_TIMEOUT, step, num("timeout_rate"));
                put(VAL_NAV_TIME, step, num("nav_time_s"));
                put(VAL_DISC, step, num("discomfort"));
                put(VAL_RETURN, step, num("mean_return"));
            }
            Some("rl") => {
                let Some(step) = v.get("episode").and_then(|e| e.as_i64()).map(|e| e + 1) else {
                    return out;
                };
                put(TD_LOSS, step, num("loss"));
                put(EPISODIC_RETURN, step, num("return_sum"));
                put(EPSILON, step, num("epsilon"));
                put(SUCCESS_WINDOW, step, num("success_rate_window"));
                put(COLLISION_WINDOW, step, num("collision_rate_window"));
                put(TIMEOUT_WINDOW, step, num("timeout_rate_window"));
                if let Some(wall) = num("wall_s") {
                    put(EPISODES_PER_S, step, self.all.push(wall));
                    let actor = v.get("actor").and_then(|a| a.as_u64()).unwrap_or(0) as u32;
                    let rate = self.actors.entry(actor).or_default().push(wall);
                    put(&actor_episodes_per_s(actor), step, rate);
                }
                if let Mode::SingleProcess {
                    updates_per_episode,
                } = self.mode
                {
                    put(UPDATES_PER_EPISODE, step, Some(updates_per_episode));
                    put(POLICY_LAG_MEAN, step, Some(0.0));
                    put(POLICY_LAG_MAX, step, Some(0.0));
                    put(ACTORS_ALIVE, step, Some(1.0));
                }
            }
            _ => {}
        }
        out
    }
}

/// The points of live metrics messages (`fsrl/<run>/metrics/**`), for a board that sees the run
/// only through them (`fsrl watch --tensorboard`: [`LiveMapper::all`]) or that reads the run's
/// logs too (`fsrl train`'s launcher: [`LiveMapper::not_in_log`], only the tags of [`is_live`]).
#[derive(Debug, Clone, Default)]
pub struct LiveMapper {
    everything: bool,
    /// The learner's RL episodes, as of its last message (the step of the actors' points).
    episodes: u64,
    learner: Option<(u64, f64)>,
    actors: BTreeMap<u32, (u64, f64)>,
}

impl LiveMapper {
    pub fn all() -> Self {
        LiveMapper {
            everything: true,
            ..Default::default()
        }
    }

    pub fn not_in_log() -> Self {
        LiveMapper::default()
    }

    /// The points of one message from `sender`. Rates are between one message of a sender and
    /// the next (a restarted sender, whose clock or count goes back, starts again).
    pub fn message(&mut self, sender: SenderId, m: &Metrics) -> Vec<Point> {
        let v = |k: &str| m.values.get(k).copied().filter(|x| x.is_finite());
        let mut out = Vec::new();
        let mut put = |tag: &str, step: u64, value: Option<f64>| {
            if let Some(value) = value {
                out.push((tag.to_string(), step as i64, value));
            }
        };
        let rate = |last: Option<(u64, f64)>| {
            let (e0, w0) = last?;
            (m.episodes >= e0 && m.wall_time_s > w0)
                .then(|| (m.episodes - e0) as f64 / (m.wall_time_s - w0))
        };
        match sender.role {
            Role::Learner => {
                let training = v("imitation_done").is_some_and(|d| d > 0.5);
                if !training {
                    if let Some(epoch) = v("imitation_epoch") {
                        if self.everything {
                            put(IMITATION_LOSS, epoch as u64, v("loss"));
                        }
                    }
                    return out;
                }
                self.episodes = m.episodes;
                let step = m.episodes;
                if step == 0 {
                    self.learner = Some((m.episodes, m.wall_time_s));
                    return out;
                }
                put(UPDATES_PER_EPISODE, step, v("updates_per_episode"));
                put(POLICY_LAG_MEAN, step, v("policy_lag_mean"));
                put(POLICY_LAG_MAX, step, v("policy_lag_max"));
                put(ACTORS_ALIVE, step, v("actors_alive"));
                if self.everything {
                    put(TD_LOSS, step, v("loss"));
                    put(EPSILON, step, v("epsilon"));
                    put(SUCCESS_WINDOW, step, v("success_rate"));
                    put(COLLISION_WINDOW, step, v("collision_rate"));
                    put(TIMEOUT_WINDOW, step, v("timeout_rate"));
                    put(EPISODES_PER_S, step, rate(self.learner));
                }
                self.learner = Some((m.episodes, m.wall_time_s));
            }
            Role::Actor if self.everything => {
                let last = self
                    .actors
                    .insert(sender.index, (m.episodes, m.wall_time_s));
                if self.episodes > 0 {
                    put(
                        &actor_episodes_per_s(sender.index),
                        self.episodes,
                        rate(last),
                    );
                }
            }
            Role::Evaluator if self.everything => {
                if let Some(step) = v("validation_episode") {
                    let step = step as u64;
                    put(VAL_SUCCESS, step, v("validation_success_rate"));
                    put(VAL_COLLISION, step, v("validation_collision_rate"));
                    put(VAL_TIMEOUT, step, v("validation_timeout_rate"));
                    put(VAL_NAV_TIME, step, v("validation_nav_time_s"));
                    put(VAL_DISC, step, v("validation_discomfort"));
                    put(VAL_RETURN, step, v("validation_mean_return"));
                }
            }
            _ => {}
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn tags(points: &[Point]) -> Vec<&str> {
        points.iter().map(|p| p.0.as_str()).collect()
    }

    #[test]
    fn log_lines_give_their_points_at_episodes_done() {
        let mut m = LogMapper::new(Mode::SingleProcess {
            updates_per_episode: 20.0,
        });
        let p = m.line(&json!({"phase": "imitation", "epoch": 0, "loss": 0.5}));
        assert_eq!(p, vec![(IMITATION_LOSS.to_string(), 1, 0.5)]);
        let rl = |e: u64, wall: f64| json!({"phase": "rl", "episode": e, "loss": 0.25, "return_sum": 1.0, "epsilon": 0.5, "success_rate_window": 0.0, "collision_rate_window": 1.0, "timeout_rate_window": 0.0, "wall_s": wall});
        let p = m.line(&rl(0, 10.0));
        assert!(p.iter().all(|(_, step, _)| *step == 1));
        // No rate from one episode; the single process's constants are there.
        assert!(!tags(&p).contains(&EPISODES_PER_S));
        assert!(p.contains(&(UPDATES_PER_EPISODE.to_string(), 1, 20.0)));
        assert!(p.contains(&(ACTORS_ALIVE.to_string(), 1, 1.0)));
        let p = m.line(&rl(1, 10.5));
        assert!(p.contains(&(EPISODES_PER_S.to_string(), 2, 2.0)));
        assert!(p.contains(&(actor_episodes_per_s(0), 2, 2.0)));
        // Over a window of RATE_WINDOW episodes.
        for e in 2..30 {
            m.line(&rl(e, 10.5 + (e - 1) as f64));
        }
        let p = m.line(&rl(30, 39.5));
        assert!(p.contains(&(EPISODES_PER_S.to_string(), 31, 1.0)));
        let p = m.line(&json!({"phase": "validation", "episode": 30, "success_rate": 0.75, "collision_rate": 0.25, "timeout_rate": 0.0, "discomfort": 0.125, "nav_time_s": null, "mean_return": 0.5}));
        assert_eq!(p.len(), 5, "no Nav. Time without a success: {p:?}");
        assert!(p.contains(&(VAL_DISC.to_string(), 30, 0.125)));
        assert!(m.line(&json!({"phase": "other"})).is_empty());
        assert!(m.line(&json!({"phase": "rl"})).is_empty());
    }

    #[test]
    fn a_distributed_log_leaves_the_live_tags_to_the_learner() {
        let mut m = LogMapper::new(Mode::Distributed);
        let p =
            m.line(&json!({"phase": "rl", "episode": 4, "loss": 0.5, "wall_s": 1.0, "actor": 3}));
        assert!(p.iter().all(|(t, _, _)| !is_live(t)));
        let p =
            m.line(&json!({"phase": "rl", "episode": 5, "loss": 0.5, "wall_s": 2.0, "actor": 3}));
        assert!(p.contains(&(actor_episodes_per_s(3), 6, 1.0)));
    }

    fn msg(episodes: u64, wall: f64, values: &[(&str, f64)]) -> Metrics {
        Metrics {
            env_steps: 0,
            episodes,
            wall_time_s: wall,
            values: values.iter().map(|(k, v)| (k.to_string(), *v)).collect(),
        }
    }

    #[test]
    fn live_metrics_give_the_same_tags() {
        let learner = SenderId::new(Role::Learner, 0);
        let actor = SenderId::new(Role::Actor, 1);
        let mut all = LiveMapper::all();
        let p = all.message(
            learner,
            &msg(0, 1.0, &[("imitation_epoch", 3.0), ("loss", 0.5)]),
        );
        assert_eq!(p, vec![(IMITATION_LOSS.to_string(), 3, 0.5)]);
        let training = [
            ("imitation_done", 1.0),
            ("loss", 0.25),
            ("actors_alive", 2.0),
            ("updates_per_episode", 8.0),
        ];
        assert!(all.message(learner, &msg(0, 2.0, &training)).is_empty());
        all.message(actor, &msg(10, 2.0, &[]));
        let p = all.message(learner, &msg(4, 4.0, &training));
        assert!(p.contains(&(TD_LOSS.to_string(), 4, 0.25)));
        assert!(p.contains(&(ACTORS_ALIVE.to_string(), 4, 2.0)));
        assert!(p.contains(&(EPISODES_PER_S.to_string(), 4, 2.0)));
        let p = all.message(actor, &msg(16, 5.0, &[]));
        assert_eq!(p, vec![(actor_episodes_per_s(1), 4, 2.0)]);
        // A restarted actor starts its rate again.
        assert!(all.message(actor, &msg(1, 0.5, &[])).is_empty());
        let evaluator = SenderId::new(Role::Evaluator, 0);
        let p = all.message(
            evaluator,
            &msg(
                4,
                9.0,
                &[
                    ("validation_episode", 4.0),
                    ("validation_success_rate", 1.0),
                ],
            ),
        );
        assert_eq!(p, vec![(VAL_SUCCESS.to_string(), 4, 1.0)]);
        // Beside the log: only the learner's live tags.
        let mut some = LiveMapper::not_in_log();
        let p = some.message(learner, &msg(4, 4.0, &training));
        assert!(
            !p.is_empty() && p.iter().all(|(t, _, _)| is_live(t)),
            "{p:?}"
        );
        assert!(some
            .message(evaluator, &msg(4, 9.0, &[("validation_episode", 4.0)]))
            .is_empty());
    }
}
