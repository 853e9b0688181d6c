//! Scenario generation for the six settings (SPEC §2): where the robot and the humans start,
//! where they go, and which humans stand still. A scenario is a pure function of
//! (config, setting, seed).

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::config::{EnvKind, Setting, SimConfig};
use crate::geom::{heading, Vec2};
use crate::robot::RobotState;

// Env 3's fixed standing humans live in `config`, beside `EnvKind` (its check counts them).
pub use crate::config::ENV3_TRAPS;

/// A human: position, velocity and goal in the world frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HumanState {
    pub position: Vec2,
    pub velocity: Vec2,
    pub goal: Vec2,
    pub radius_m: f64,
    pub v_pref_mps: f64,
    /// A standing human never moves.
    pub standing: bool,
}

/// The initial state of an episode.
#[derive(Debug, Clone, PartialEq)]
pub struct Scenario {
    pub robot: RobotState,
    pub humans: Vec<HumanState>,
}

/// A scenario that could not be built.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ScenarioError {
    #[error("could not place human {human} of {setting} (seed {seed}) after {attempts} draws: the arena is too crowded for this configuration")]
    TooCrowded {
        setting: Setting,
        seed: u64,
        human: usize,
        attempts: usize,
    },
    #[error("{setting} has {fixed} fixed standing humans but the configuration asks for {asked}")]
    TrapCount {
        setting: Setting,
        fixed: usize,
        asked: usize,
    },
}

/// The robot at its start, at rest, facing `heading_rad`.
pub fn initial_robot(cfg: &SimConfig) -> RobotState {
    let r = &cfg.robot;
    RobotState {
        position: Vec2::new(r.start_m[0], r.start_m[1]),
        velocity: Vec2::zeros(),
        goal: Vec2::new(r.goal_m[0], r.goal_m[1]),
        heading_rad: crate::geom::wrap_angle(r.heading_rad),
        radius_m: r.radius_m,
        v_pref_mps: r.v_pref_mps,
    }
}

struct Placed {
    position: Vec2,
    goal: Vec2,
    radius_m: f64,
}

fn clear_of(placed: &[Placed], p: Vec2, radius_m: f64, gap_m: f64) -> bool {
    placed.iter().all(|a| {
        let min = radius_m + a.radius_m + gap_m;
        (p - a.position).norm() >= min && (p - a.goal).norm() >= min
    })
}

impl Scenario {
    /// Generates the scenario of `setting` for `seed`. The config must be valid
    /// ([`SimConfig::validate`]).
    pub fn generate(
        cfg: &SimConfig,
        setting: Setting,
        seed: u64,
    ) -> Result<Scenario, ScenarioError> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let robot = initial_robot(cfg);
        let h = &cfg.humans;
        let standing_count = match setting.env {
            EnvKind::Env1 => 0,
            EnvKind::Env2 => h.standing,
            EnvKind::Env3 => {
                if h.standing != ENV3_TRAPS.len() {
                    return Err(ScenarioError::TrapCount {
                        setting,
                        fixed: ENV3_TRAPS.len(),
                        asked: h.standing,
                    });
                }
                h.standing
            }
        };
        let mut placed = vec![Placed {
            position: robot.position,
            goal: robot.goal,
            radius_m: robot.radius_m,
        }];
        let too_crowded = |human: usize| ScenarioError::TooCrowded {
            setting,
            seed,
            human,
            attempts: h.max_spawn_attempts,
        };

        // Standing humans first, so that dynamic ones are drawn clear of them.
        let mut standing = Vec::with_capacity(standing_count);
        // `k` names the human in errors as well as indexing the fixed traps.
        #[allow(clippy::needless_range_loop)]
        for k in 0..standing_count {
            let position = match setting.env {
                EnvKind::Env3 => Vec2::new(ENV3_TRAPS[k][0], ENV3_TRAPS[k][1]),
                _ => {
                    let mut found = None;
                    for _ in 0..h.max_spawn_attempts {
                        let p = Vec2::new(
                            (rng.gen::<f64>() * 2.0 - 1.0) * h.square_half_width_m,
                            (rng.gen::<f64>() * 2.0 - 1.0) * h.square_half_width_m,
                        );
                        let clear_robot = (p - robot.position).norm()
                            >= h.standing_clear_of_robot_m
                            && (p - robot.goal).norm() >= h.standing_clear_of_robot_m;
                        if clear_robot && clear_of(&placed, p, h.radius_m, h.spawn_gap_m) {
                            found = Some(p);
                            break;
                        }
                    }
                    found.ok_or_else(|| too_crowded(h.count - standing_count + k))?
                }
            };
            placed.push(Placed {
                position,
                goal: position,
                radius_m: h.radius_m,
            });
            standing.push(HumanState {
                position,
                velocity: Vec2::zeros(),
                goal: position,
                radius_m: h.radius_m,
                v_pref_mps: h.v_pref_mps,
                standing: true,
            });
        }

        // Dynamic humans: circle crossing.
        let dynamic_count = h.count - standing_count;
        let mut humans = Vec::with_capacity(h.count);
        for k in 0..dynamic_count {
            let mut found = None;
            for _ in 0..h.max_spawn_attempts {
                let angle = rng.gen::<f64>() * std::f64::consts::TAU;
                let noise = Vec2::new(
                    (rng.gen::<f64>() * 2.0 - 1.0) * h.start_noise_m,
                    (rng.gen::<f64>() * 2.0 - 1.0) * h.start_noise_m,
                );
                let p = heading(angle) * h.circle_radius_m + noise;
                if clear_of(&placed, p, h.radius_m, h.spawn_gap_m) {
                    found = Some(p);
                    break;
                }
            }
            let position = found.ok_or_else(|| too_crowded(k))?;
            placed.push(Placed {
                position,
                goal: -position,
                radius_m: h.radius_m,
            });
            humans.push(HumanState {
                position,
                velocity: Vec2::zeros(),
                goal: -position,
                radius_m: h.radius_m,
                v_pref_mps: h.v_pref_mps,
                standing: false,
            });
        }
        humans.extend(standing);
        Ok(Scenario { robot, humans })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn same_setting_and_seed_give_the_same_scenario() {
        let cfg = SimConfig::default();
        for s in Setting::ALL {
            let a = Scenario::generate(&cfg, s, 1234).unwrap();
            let b = Scenario::generate(&cfg, s, 1234).unwrap();
            assert_eq!(a, b);
            let c = Scenario::generate(&cfg, s, 1235).unwrap();
            assert_ne!(a, c);
        }
    }

    #[test]
    fn settings_follow_the_spec_rules() {
        let cfg = SimConfig::default();
        for seed in 0..200 {
            for s in Setting::ALL {
                let sc = Scenario::generate(&cfg, s, seed).unwrap();
                assert_eq!(sc.humans.len(), 10);
                let n_standing = sc.humans.iter().filter(|h| h.standing).count();
                let expected = if s.env == EnvKind::Env1 { 0 } else { 5 };
                assert_eq!(n_standing, expected, "{s} seed {seed}");
                for (i, h) in sc.humans.iter().enumerate() {
                    if h.standing {
                        assert_eq!(h.goal, h.position);
                        if s.env == EnvKind::Env2 {
                            assert!(h.position.x.abs() <= 4.0 && h.position.y.abs() <= 4.0);
                            assert!((h.position - sc.robot.position).norm() >= 1.0);
                            assert!((h.position - sc.robot.goal).norm() >= 1.0);
                        }
                    } else {
                        assert_eq!(h.goal, -h.position);
                        let r = h.position.norm();
                        assert!((4.0 - 0.75..=4.0 + 0.75).contains(&r), "{r}");
                    }
                    // Every human starts clear of every other agent's position (gap 0.2 m),
                    // the robot included; fixed traps are exempt from each other.
                    let min = 0.3 + 0.3 + 0.2 - 1e-12;
                    assert!((h.position - sc.robot.position).norm() >= min);
                    for (j, o) in sc.humans.iter().enumerate() {
                        let both_fixed = s.env == EnvKind::Env3 && h.standing && o.standing;
                        if i != j && !both_fixed {
                            assert!(
                                (h.position - o.position).norm() >= min,
                                "{s} {seed} {i} {j}"
                            );
                        }
                    }
                }
                if s.env == EnvKind::Env3 {
                    let fixed: Vec<[f64; 2]> = sc
                        .humans
                        .iter()
                        .filter(|h| h.standing)
                        .map(|h| [h.position.x, h.position.y])
                        .collect();
                    assert_eq!(fixed, ENV3_TRAPS.to_vec());
                }
            }
        }
    }

    #[test]
    fn an_impossible_arena_is_an_error_not_a_hang() {
        let mut cfg = SimConfig::default();
        cfg.humans.count = 60;
        cfg.humans.max_spawn_attempts = 200;
        let err = Scenario::generate(&cfg, Setting::ALL[0], 1).unwrap_err();
        assert!(matches!(err, ScenarioError::TooCrowded { .. }), "{err}");
    }
}
