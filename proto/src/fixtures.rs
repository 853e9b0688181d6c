//! Deterministic sample messages for tests and benchmarks (here and in other crates).

use std::collections::BTreeMap;

use crate::control::{Ack, Control, CreditGrant, RunPhase};
use crate::header::{Body, Header};
use crate::ids::{RunId, SenderId};
use crate::reports::{EvalReport, Metrics, ProcessState, SettingReport, Status};
use crate::transitions::{
    EpisodeMeta, HumanState, Outcome, RewardTerms, RobotState, TransitionBatch,
};
use crate::weights::{NetworkDesc, NetworkKind, TensorDesc, Weights};

/// The SARL value network's tensors (spec §4): 96 502 parameters.
pub fn sarl_network() -> NetworkDesc {
    let mut tensors = Vec::new();
    let mut linear = |name: &str, inp: u32, out: u32| {
        tensors.push(TensorDesc::new(format!("{name}.weight"), [out, inp]));
        tensors.push(TensorDesc::new(format!("{name}.bias"), [out]));
    };
    linear("mlp1.0", 13, 150);
    linear("mlp1.1", 150, 100);
    linear("mlp2.0", 100, 100);
    linear("mlp2.1", 100, 50);
    linear("attention.0", 200, 100);
    linear("attention.1", 100, 100);
    linear("attention.2", 100, 1);
    linear("mlp3.0", 56, 150);
    linear("mlp3.1", 150, 100);
    linear("mlp3.2", 100, 100);
    linear("mlp3.3", 100, 1);
    NetworkDesc {
        kind: NetworkKind::Sarl,
        tensors,
    }
}

/// SARL-sized weights with deterministic parameter values.
pub fn sarl_weights(version: u64) -> Weights {
    let network = sarl_network();
    let n = network.param_count().unwrap_or(0) as usize;
    let params = (0..n)
        .map(|i| ((i as f32) * 0.618_034 + version as f32).sin() * 0.1)
        .collect();
    // The description and values above are valid by construction.
    Weights::new(version, network, params).unwrap_or_else(|e| panic!("fixture invalid: {e}"))
}

/// A whole episode of `n_steps` steps with `n_humans` humans (half of them standing), ending in
/// `ReachGoal`.
pub fn episode(n_steps: u32, n_humans: u32, episode: u64) -> TransitionBatch {
    let robot = |t: u32| RobotState {
        px_m: 0.0,
        py_m: -4.0 + 0.15 * t as f32,
        vx_mps: 0.0,
        vy_mps: 0.6,
        radius_m: 0.3,
        gx_m: 0.0,
        gy_m: 4.0,
        v_pref_mps: 1.0,
        theta_rad: std::f32::consts::FRAC_PI_2,
    };
    let humans = |t: u32| -> Vec<HumanState> {
        (0..n_humans)
            .map(|i| {
                let phi = i as f32 * 0.7 + t as f32 * 0.01;
                HumanState {
                    px_m: 4.0 * phi.cos(),
                    py_m: 4.0 * phi.sin(),
                    vx_mps: -0.5 * phi.cos(),
                    vy_mps: -0.5 * phi.sin(),
                    radius_m: 0.3,
                }
            })
            .collect()
    };
    let meta = EpisodeMeta {
        setting: "env2-invisible".into(),
        seed: 2000 + episode,
        episode,
        n_actions: 51,
        epsilon: 0.25,
        human_standing: (0..n_humans).map(|i| i % 2 == 1).collect(),
    };
    let mut b = TransitionBatch::builder(meta, robot(0), &humans(0));
    for t in 0..n_steps {
        let r = RewardTerms {
            r_c: 0.0,
            r_st: -0.01,
            r_dy: -0.02,
            r_t: 0.0,
            total: -0.03,
        };
        b.push_step(
            (t % 51) as u16,
            r,
            0.5 + 0.01 * t as f32,
            &robot(t + 1),
            &humans(t + 1),
        );
    }
    b.finish(Outcome::ReachGoal)
        .unwrap_or_else(|e| panic!("fixture invalid: {e}"))
}

/// An evaluation report over the six settings.
pub fn eval_report() -> EvalReport {
    let settings = ["env1", "env2", "env3"]
        .iter()
        .flat_map(|e| ["invisible", "visible"].map(|v| format!("{e}-{v}")))
        .map(|setting| SettingReport {
            setting,
            episodes: 500,
            success_rate: 0.95,
            collision_rate: 0.03,
            timeout_rate: 0.02,
            nav_time_s: Some(10.9),
            discomfort: 0.04,
            mean_return: 0.31,
            path_length_m: 8.7,
            smoothness_rad: 0.05,
            wall_collision_rate: None,
            people_collision_rate: None,
            frozen_rate: None,
        })
        .collect();
    EvalReport {
        trained_episodes: 10_000,
        final_snapshot: true,
        settings,
    }
}

/// A metrics message with a few named values.
pub fn metrics() -> Metrics {
    let values = BTreeMap::from([
        ("loss".to_string(), 0.0125),
        ("actor_fps".to_string(), 812.5),
        ("policy_lag_max".to_string(), 3.0),
    ]);
    Metrics {
        env_steps: 123_456,
        episodes: 2_345,
        wall_time_s: 61.5,
        values,
    }
}

/// A heartbeat.
pub fn status() -> Status {
    Status {
        state: ProcessState::Running,
        uptime_s: 12.5,
        env_steps: 4_500,
        episodes: 100,
        detail: "ok".into(),
    }
}

/// An acknowledgement.
pub fn ack() -> Ack {
    Ack {
        actor: 3,
        acked_below: 40,
        episodes: vec![42, 45],
        learner: 0x5eed,
    }
}

/// A control message.
pub fn control() -> Control {
    Control {
        phase: RunPhase::Training,
        epsilon: 0.4,
        credits: vec![
            CreditGrant {
                actor: 0,
                episode_budget: 50,
            },
            CreditGrant {
                actor: 1,
                episode_budget: 48,
            },
        ],
        final_rl_episodes: None,
    }
}

/// Run id `fixture`.
pub fn run() -> RunId {
    RunId::new("fixture").unwrap_or_else(|e| panic!("fixture invalid: {e}"))
}

/// A header for a `B` from `sender` in run [`run`].
pub fn header<B: Body>(sender: SenderId, seq: u64, policy_version: u64) -> Header {
    Header::new::<B>(run(), sender, seq, policy_version)
}
