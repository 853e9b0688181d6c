//! Explicit conversion at the wire edge: a recorded [`EpisodeData`] to and from `proto`'s
//! [`TransitionBatch`]. Internal types never derive `Serialize`; this is the one place they meet.
//!
//! States travel as f32 (the network reads f32 features anyway); a round trip therefore rounds
//! positions and velocities to f32.

use proto::{EpisodeMeta, TransitionBatch};
use sim::geom::wrap_angle;
use sim::{EpisodeSummary, Outcome, RewardTerms, RobotState, Setting, SimConfig, Vec2};

use crate::joint::HumanObs;
use crate::rollout::{EpisodeData, JointState};

/// Why a batch cannot become an episode.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum WireError {
    #[error(transparent)]
    Invalid(#[from] proto::ValidationError),
    #[error("unknown setting `{0}`")]
    UnknownSetting(String),
    #[error(
        "episode {episode} arrived in chunks (chunk {chunk}); the learner takes whole episodes"
    )]
    Chunked { episode: u64, chunk: u32 },
    #[error("episode {0} has not finished (outcome running)")]
    Unfinished(u64),
    #[error("malformed batch: missing {0}")]
    Malformed(&'static str),
    #[error("episode {episode}: {what} out of range: {value} (limit {limit})")]
    OutOfRange {
        episode: u64,
        what: &'static str,
        value: f64,
        limit: String,
    },
}

/// Physical limits of an episode of `cfg`'s world: what any honest actor can send. Positions
/// stay within where an agent can walk in one episode, speeds within twice the fastest preferred
/// speed, radii and v_pref within twice the configured ones, rewards within what one step can
/// pay ([`sim::RewardConfig::step_bounds`]). Finite values that pass `proto`'s validation but
/// not these (a reward of 1e30, a position of 3e38) would overflow the f32 loss.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EpisodeLimits {
    pub position_m: f64,
    pub speed_mps: f64,
    pub radius_m: f64,
    pub v_pref_mps: f64,
    pub reward: (f64, f64),
    pub steps: u64,
}

impl EpisodeLimits {
    pub fn of(cfg: &SimConfig) -> Self {
        let fastest = cfg.robot.v_pref_mps.max(cfg.humans.v_pref_mps).abs();
        let world_m = cfg.humans.circle_radius_m.abs()
            + cfg.humans.square_half_width_m.abs()
            + cfg.humans.start_noise_m.abs() * fastest
            + cfg.robot.start_m[0].abs().max(cfg.robot.start_m[1].abs())
            + cfg.robot.goal_m[0].abs().max(cfg.robot.goal_m[1].abs());
        let radius_m = 2.0 * cfg.robot.radius_m.max(cfg.humans.radius_m).abs();
        // Tolerance for the f32 wire encoding of f64 rewards.
        let (lo, hi) = cfg.reward.step_bounds(radius_m);
        let slack = 1e-4 * (1.0 + lo.abs().max(hi.abs()));
        Self {
            position_m: world_m + 2.0 * fastest * cfg.time_limit_s + 10.0,
            speed_mps: 2.0 * fastest + 1e-3,
            radius_m,
            v_pref_mps: 2.0 * fastest + 1e-3,
            reward: (lo - slack, hi + slack),
            steps: (cfg.time_limit_s / cfg.dt_s).ceil() as u64 + 1,
        }
    }

    /// Checks every state, reward and the length of `ep` (numbered `episode`).
    pub fn check(&self, ep: &EpisodeData, episode: u64) -> Result<(), WireError> {
        let out = |what: &'static str, value: f64, limit: String| WireError::OutOfRange {
            episode,
            what,
            value,
            limit,
        };
        let within = |what: &'static str, value: f64, limit: f64| {
            if value.is_finite() && value.abs() <= limit {
                Ok(())
            } else {
                Err(out(what, value, format!("±{limit}")))
            }
        };
        let positive = |what: &'static str, value: f64, limit: f64| {
            if value > 0.0 && value <= limit {
                Ok(())
            } else {
                Err(out(what, value, format!("(0, {limit}]")))
            }
        };
        if ep.actions.len() as u64 > self.steps {
            return Err(out(
                "steps",
                ep.actions.len() as f64,
                self.steps.to_string(),
            ));
        }
        for s in &ep.states {
            let r = &s.robot;
            for v in [r.position.x, r.position.y, r.goal.x, r.goal.y] {
                within("robot position", v, self.position_m)?;
            }
            within("robot speed", r.velocity.norm(), self.speed_mps)?;
            within("robot heading", r.heading_rad, 1e3)?;
            positive("robot radius", r.radius_m, self.radius_m)?;
            positive("robot v_pref", r.v_pref_mps, self.v_pref_mps)?;
            for h in &s.humans {
                within("human position", h.position.x, self.position_m)?;
                within("human position", h.position.y, self.position_m)?;
                within("human speed", h.velocity.norm(), self.speed_mps)?;
                // Radius 0: a static obstacle point among walls (`HumanObs::obstacle`), which
                // never moves.
                if h.radius_m == 0.0 && h.velocity == Vec2::zeros() {
                    continue;
                }
                positive("human radius", h.radius_m, self.radius_m)?;
            }
        }
        let (lo, hi) = self.reward;
        for r in &ep.rewards {
            if !(r.total >= lo && r.total <= hi) {
                return Err(out("reward", r.total, format!("[{lo}, {hi}]")));
            }
        }
        if !(0.0..=1.0).contains(&ep.epsilon) {
            return Err(out("epsilon", ep.epsilon, "[0, 1]".into()));
        }
        Ok(())
    }
}

fn outcome_to_wire(o: Outcome) -> proto::Outcome {
    match o {
        Outcome::Running => proto::Outcome::Running,
        Outcome::Collision => proto::Outcome::Collision,
        Outcome::ReachGoal => proto::Outcome::ReachGoal,
        Outcome::Timeout => proto::Outcome::Timeout,
    }
}

fn outcome_from_wire(o: proto::Outcome) -> Outcome {
    match o {
        proto::Outcome::Running => Outcome::Running,
        proto::Outcome::Collision => Outcome::Collision,
        proto::Outcome::ReachGoal => Outcome::ReachGoal,
        proto::Outcome::Timeout => Outcome::Timeout,
    }
}

fn robot_to_wire(r: &RobotState) -> proto::RobotState {
    proto::RobotState {
        px_m: r.position.x as f32,
        py_m: r.position.y as f32,
        vx_mps: r.velocity.x as f32,
        vy_mps: r.velocity.y as f32,
        radius_m: r.radius_m as f32,
        gx_m: r.goal.x as f32,
        gy_m: r.goal.y as f32,
        v_pref_mps: r.v_pref_mps as f32,
        theta_rad: r.heading_rad as f32,
    }
}

fn robot_from_wire(r: &proto::RobotState) -> RobotState {
    RobotState {
        position: Vec2::new(r.px_m as f64, r.py_m as f64),
        velocity: Vec2::new(r.vx_mps as f64, r.vy_mps as f64),
        goal: Vec2::new(r.gx_m as f64, r.gy_m as f64),
        heading_rad: r.theta_rad as f64,
        radius_m: r.radius_m as f64,
        v_pref_mps: r.v_pref_mps as f64,
    }
}

fn human_to_wire(h: &HumanObs) -> proto::HumanState {
    proto::HumanState {
        px_m: h.position.x as f32,
        py_m: h.position.y as f32,
        vx_mps: h.velocity.x as f32,
        vy_mps: h.velocity.y as f32,
        radius_m: h.radius_m as f32,
    }
}

fn human_from_wire(h: &proto::HumanState) -> HumanObs {
    HumanObs {
        position: Vec2::new(h.px_m as f64, h.py_m as f64),
        velocity: Vec2::new(h.vx_mps as f64, h.vy_mps as f64),
        radius_m: h.radius_m as f64,
    }
}

/// The episode as one whole-episode batch, numbered `episode` for its actor.
pub fn to_batch(
    ep: &EpisodeData,
    episode: u64,
    n_actions: u16,
) -> Result<TransitionBatch, proto::ValidationError> {
    let humans0: Vec<proto::HumanState> = ep.states[0].humans.iter().map(human_to_wire).collect();
    let mut b = TransitionBatch::builder(
        EpisodeMeta {
            setting: ep.setting.name().to_string(),
            seed: ep.seed,
            episode,
            n_actions,
            epsilon: ep.epsilon as f32,
            human_standing: ep.standing.clone(),
        },
        robot_to_wire(&ep.states[0].robot),
        &humans0,
    );
    let mut humans = Vec::with_capacity(humans0.len());
    for t in 0..ep.actions.len() {
        let r = &ep.rewards[t];
        let next = &ep.states[t + 1];
        humans.clear();
        humans.extend(next.humans.iter().map(human_to_wire));
        b.push_step(
            ep.actions[t],
            proto::RewardTerms {
                r_c: r.collision_goal as f32,
                r_st: r.standing as f32,
                r_dy: r.dynamic as f32,
                r_t: r.time as f32,
                total: r.total as f32,
            },
            ep.closest_m[t] as f32,
            &robot_to_wire(&next.robot),
            &humans,
        );
    }
    b.finish(outcome_to_wire(ep.outcome))
}

/// The episode of a validated whole-episode batch produced by weights `policy_version`.
/// `cfg` gives dt and the comfort distance for the summary.
pub fn from_batch(
    b: &TransitionBatch,
    policy_version: u64,
    cfg: &SimConfig,
) -> Result<EpisodeData, WireError> {
    proto::Body::validate(b)?;
    if b.chunk != 0 || !b.last_chunk {
        return Err(WireError::Chunked {
            episode: b.episode,
            chunk: b.chunk,
        });
    }
    let outcome = outcome_from_wire(b.outcome);
    if outcome == Outcome::Running {
        return Err(WireError::Unfinished(b.episode));
    }
    let setting: Setting = b
        .setting
        .parse()
        .map_err(|_| WireError::UnknownSetting(b.setting.clone()))?;
    let t_len = b.n_steps as usize;
    let h = b.n_humans as usize;
    let mut states = Vec::with_capacity(t_len + 1);
    for t in 0..=t_len {
        // Validation checked the lengths; a missing row is still an error, never a panic.
        let robot = b
            .robot_state(t)
            .map(|r| robot_from_wire(&r))
            .ok_or(WireError::Malformed("robot state row"))?;
        let humans = (0..h)
            .map(|i| b.human_state(t, i).map(|s| human_from_wire(&s)))
            .collect::<Option<Vec<_>>>()
            .ok_or(WireError::Malformed("human state row"))?;
        states.push(JointState { robot, humans });
    }
    let rewards: Vec<RewardTerms> = (0..t_len)
        .map(|t| {
            let r = b.reward(t).unwrap_or_default();
            RewardTerms {
                collision_goal: r.r_c as f64,
                standing: r.r_st as f64,
                dynamic: r.r_dy as f64,
                time: r.r_t as f64,
                total: r.total as f64,
            }
        })
        .collect();
    let closest_m: Vec<f64> = b.closest_dist_m.iter().map(|&d| d as f64).collect();
    let mut summary = EpisodeSummary {
        outcome,
        steps: b.n_steps,
        time_s: b.n_steps as f64 * cfg.dt_s,
        danger_steps: 0,
        path_length_m: 0.0,
        total_abs_rotation_rad: 0.0,
        return_sum: rewards.iter().map(|r| r.total).sum(),
        min_closest_m: closest_m.iter().copied().fold(f64::INFINITY, f64::min),
        min_danger_m: f64::INFINITY,
        wall_collision: false,
        frozen: false,
    };
    for t in 0..t_len {
        let (a, z) = (&states[t].robot, &states[t + 1].robot);
        summary.path_length_m += (z.position - a.position).norm();
        summary.total_abs_rotation_rad += wrap_angle(z.heading_rad - a.heading_rad).abs();
        let terminal_hit =
            t + 1 == t_len && matches!(outcome, Outcome::Collision | Outcome::ReachGoal);
        if closest_m[t] < cfg.reward.comfort_dist_m && !terminal_hit {
            summary.danger_steps += 1;
            summary.min_danger_m = summary.min_danger_m.min(closest_m[t]);
        }
    }
    let positions: Vec<Vec2> = states.iter().map(|s| s.robot.position).collect();
    summary.frozen = sim::episode::is_frozen(outcome, &positions, cfg.dt_s);
    let ep = EpisodeData {
        setting,
        seed: b.seed,
        states,
        actions: b.actions.clone(),
        rewards,
        closest_m,
        standing: b.human_standing.clone(),
        outcome,
        epsilon: b.epsilon as f64,
        policy_version,
        summary,
    };
    EpisodeLimits::of(cfg).check(&ep, b.episode)?;
    Ok(ep)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rollout::{rollout, Behaviour};
    use sim::Env;

    /// Every honest episode passes the limits: ORCA and a random-acting network (ε = 1, the
    /// widest spread of robot motions) in all six settings and the walled ones (whose static
    /// obstacle entities have radius 0), under the default and the SPEC literal rewards.
    #[test]
    fn honest_episodes_are_within_the_limits() {
        use crate::lookahead::{HumanModel, Lookahead};
        let net = crate::ValueNet::new(crate::NetConfig::sarl(), 3).unwrap();
        let mut literal = SimConfig::default();
        literal.reward.standing_alpha = 0.15;
        literal.reward.dynamic_beta = 0.5;
        for cfg in [SimConfig::default(), literal] {
            let limits = EpisodeLimits::of(&cfg);
            for setting in sim::Setting::every() {
                let mut env = Env::new(cfg.clone(), setting, 0).unwrap();
                let mut la =
                    Lookahead::new(0.9, HumanModel::Orca, crate::joint::HumanOrder::AsGiven);
                for seed in 0..20u64 {
                    let orca = rollout(
                        &mut env,
                        seed,
                        Behaviour::Orca {
                            safety_space_m: 0.0,
                        },
                    )
                    .unwrap();
                    limits.check(&orca, seed).unwrap();
                    let random = rollout(
                        &mut env,
                        seed,
                        Behaviour::Net {
                            net: &net,
                            lookahead: &mut la,
                            epsilon: 1.0,
                            policy_version: 0,
                        },
                    )
                    .unwrap();
                    limits.check(&random, seed).unwrap();
                    let b = to_batch(&random, seed, env.action_set().len() as u16).unwrap();
                    from_batch(&b, 0, &cfg).unwrap();
                }
            }
        }
    }

    /// Finite but unphysical values (they would overflow the f32 loss) are refused by name.
    #[test]
    fn extreme_finite_values_are_refused() {
        let cfg = SimConfig::default();
        let mut env = Env::new(cfg.clone(), "env1-invisible".parse().unwrap(), 0).unwrap();
        let ep = rollout(
            &mut env,
            5,
            Behaviour::Orca {
                safety_space_m: 0.0,
            },
        )
        .unwrap();
        let limits = EpisodeLimits::of(&cfg);
        limits.check(&ep, 1).unwrap();
        let refused = |mutate: &dyn Fn(&mut EpisodeData), what: &str| {
            let mut bad = ep.clone();
            mutate(&mut bad);
            match limits.check(&bad, 1) {
                Err(WireError::OutOfRange { what: w, .. }) => assert_eq!(w, what),
                other => panic!("{what}: {other:?}"),
            }
        };
        refused(&|e| e.rewards[0].total = 1e30, "reward");
        refused(&|e| e.rewards[0].total = 2.0, "reward");
        refused(&|e| e.states[1].robot.position.x = 3e38, "robot position");
        refused(
            &|e| e.states[1].humans[2].position.y = -1e6,
            "human position",
        );
        refused(&|e| e.states[0].humans[0].velocity.x = 1e20, "human speed");
        refused(&|e| e.states[0].robot.radius_m = 0.0, "robot radius");
        refused(&|e| e.states[0].robot.v_pref_mps = 1e9, "robot v_pref");
        refused(&|e| e.epsilon = 7.0, "epsilon");
        // Through the wire too: the batch of a poisoned episode does not decode.
        let mut bad = ep.clone();
        bad.rewards[0].total = 1e30;
        let b = to_batch(&bad, 4, env.action_set().len() as u16).unwrap();
        assert!(matches!(
            from_batch(&b, 0, &cfg),
            Err(WireError::OutOfRange { episode: 4, .. })
        ));
    }

    #[test]
    fn an_episode_survives_the_wire() {
        let cfg = SimConfig::default();
        let mut env = Env::new(cfg.clone(), "env3-visible".parse().unwrap(), 0).unwrap();
        let ep = rollout(
            &mut env,
            77,
            Behaviour::Orca {
                safety_space_m: 0.0,
            },
        )
        .unwrap();
        let batch = to_batch(&ep, 12, 51).unwrap();
        assert_eq!(batch.episode, 12);
        assert_eq!(batch.n_steps as usize, ep.steps());
        let bytes = proto::encode_message(&proto::Message::new(
            proto::RunId::new("t").unwrap(),
            proto::SenderId::new(proto::Role::Actor, 0),
            0,
            3,
            batch,
        ))
        .unwrap();
        let msg: proto::Message<TransitionBatch> = proto::decode(&bytes).unwrap();
        let back = from_batch(&msg.body, msg.header.policy_version, &cfg).unwrap();
        assert_eq!(back.policy_version, 3);
        assert_eq!(back.setting, ep.setting);
        assert_eq!(back.actions, ep.actions);
        assert_eq!(back.standing, ep.standing);
        assert_eq!(back.outcome, ep.outcome);
        assert_eq!(back.summary.steps, ep.summary.steps);
        assert_eq!(back.summary.danger_steps, ep.summary.danger_steps);
        assert!((back.summary.path_length_m - ep.summary.path_length_m).abs() < 1e-4);
        for (a, b) in back.states.iter().zip(&ep.states) {
            assert!((a.robot.position - b.robot.position).norm() < 1e-5);
            for (x, y) in a.humans.iter().zip(&b.humans) {
                assert!((x.position - y.position).norm() < 1e-5);
            }
        }
        for (a, b) in back.rewards.iter().zip(&ep.rewards) {
            assert!((a.total - b.total).abs() < 1e-6);
        }
    }
}

/// The wire description of a network: family and every tensor's name and shape.
pub fn network_desc(cfg: &crate::NetConfig) -> proto::NetworkDesc {
    let kind = match cfg.kind() {
        crate::NetKind::Sarl => proto::NetworkKind::Sarl,
        crate::NetKind::LstmRl => proto::NetworkKind::LstmRl,
    };
    let tensors = cfg
        .layout()
        .specs()
        .iter()
        .map(|s| {
            let shape = if s.cols == 1 && s.name.contains("bias") {
                vec![s.rows as u32]
            } else {
                vec![s.rows as u32, s.cols as u32]
            };
            proto::TensorDesc::new(s.name.clone(), shape)
        })
        .collect();
    proto::NetworkDesc { kind, tensors }
}

/// A weights message for `net` at `version`.
pub fn weights_message(
    net: &crate::ValueNet,
    version: u64,
) -> Result<proto::Weights, proto::ValidationError> {
    proto::Weights::new(version, network_desc(net.config()), net.params().to_vec())
}

/// Rebuilds the network of `expected` from received weights, refusing another architecture.
pub fn net_from_weights(
    w: &proto::Weights,
    expected: &crate::NetConfig,
) -> Result<crate::ValueNet, String> {
    let want = network_desc(expected);
    if w.network != want {
        return Err(format!(
            "weights describe a {:?} network with {} tensors; this process runs {:?} with {}",
            w.network.kind,
            w.network.tensors.len(),
            want.kind,
            want.tensors.len()
        ));
    }
    crate::ValueNet::from_params(expected.clone(), w.params.clone()).map_err(|e| e.to_string())
}

#[cfg(test)]
mod weight_tests {
    use super::*;
    use crate::{NetConfig, ValueNet};

    #[test]
    fn weights_round_trip_and_refuse_other_networks() {
        let net = ValueNet::new(NetConfig::sarl(), 1).unwrap();
        let w = weights_message(&net, 9).unwrap();
        assert_eq!(w.network.tensors.len(), net.config().layout().specs().len());
        let back = net_from_weights(&w, &NetConfig::sarl()).unwrap();
        assert_eq!(back.params(), net.params());
        assert!(net_from_weights(&w, &NetConfig::lstm_rl()).is_err());
    }
}
