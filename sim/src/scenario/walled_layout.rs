//! The walled settings' scenarios (issue 53): the layouts `room` and `pillars` drawn from the
//! episode's generator, the people of every walled layout placed in free space, and the
//! scenario's [`Walls`]. Part of `scenario` (a scenario is a pure function of config, setting and
//! seed); the walls themselves and the people's roadmap are [`crate::walled`]'s.

use std::sync::Arc;

use rand::Rng;

use crate::config::{EnvKind, Setting, SimConfig};
use crate::geom::{heading, Vec2};
use crate::map::{Shape, StaticMap};
use crate::walled::{fixed_map, Walls};

use super::{initial_robot, HumanState, Scenario, ScenarioError};

/// Grid cell of the reachability checks of generated layouts.
const REACH_CELL_M: f64 = 0.1;
/// Attempts at drawing the people of a layout before giving up.
const PEOPLE_ATTEMPTS: usize = 20;
/// Attempts at drawing a layout whose robot goal is reachable before giving up.
const LAYOUT_ATTEMPTS: usize = 200;

fn uniform<R: Rng>(rng: &mut R, lo: f64, hi: f64) -> f64 {
    lo + (hi - lo) * rng.gen::<f64>()
}

/// A solid rectangle of half sides (hx, hy) centred at `c`, rotated by `angle_rad`,
/// counter-clockwise.
fn rotated_box(c: Vec2, hx: f64, hy: f64, angle_rad: f64) -> Shape {
    let (s, co) = angle_rad.sin_cos();
    let corner = |x: f64, y: f64| c + Vec2::new(co * x - s * y, s * x + co * y);
    Shape::polygon(vec![
        corner(-hx, -hy),
        corner(hx, -hy),
        corner(hx, hy),
        corner(-hx, hy),
    ])
}

/// A regular polygon of `sides` with circumradius `r`, counter-clockwise.
fn regular(c: Vec2, r: f64, sides: usize, angle_rad: f64) -> Shape {
    Shape::polygon(
        (0..sides)
            .map(|k| c + heading(angle_rad + std::f64::consts::TAU * k as f64 / sides as f64) * r)
            .collect(),
    )
}

/// Draws a layout from `rng`: the room's furniture or the pillars, with the robot's goal
/// reachable from its start.
fn drawn_map<R: Rng>(
    cfg: &SimConfig,
    setting: Setting,
    seed: u64,
    rng: &mut R,
) -> Result<StaticMap, ScenarioError> {
    let robot = initial_robot(cfg);
    let fail = |why: String| ScenarioError::Layout { setting, seed, why };
    for _ in 0..LAYOUT_ATTEMPTS {
        let mut shapes = Vec::new();
        match setting.env {
            EnvKind::Room => {
                let r = &cfg.walls.room;
                let h = r.side_m / 2.0;
                shapes.push(Shape::room(Vec2::new(-h, -h), Vec2::new(h, h)));
                let count = rng.gen_range(r.furniture_min..=r.furniture_max);
                let mut centres: Vec<(Vec2, f64)> = Vec::new();
                let mut tries = 0;
                while centres.len() < count && tries < 1000 {
                    tries += 1;
                    let (hx, hy) = (
                        uniform(
                            rng,
                            r.furniture_half_side_min_m,
                            r.furniture_half_side_max_m,
                        ),
                        uniform(
                            rng,
                            r.furniture_half_side_min_m,
                            r.furniture_half_side_max_m,
                        ),
                    );
                    let bound = hx.hypot(hy);
                    let lim = h - bound - r.furniture_clearance_m;
                    if lim <= 0.0 {
                        continue;
                    }
                    let c = Vec2::new(uniform(rng, -lim, lim), uniform(rng, -lim, lim));
                    let angle = uniform(rng, 0.0, std::f64::consts::PI);
                    let clear = centres
                        .iter()
                        .all(|(o, ob)| (c - o).norm() >= bound + ob + r.furniture_clearance_m)
                        && (c - robot.position).norm() >= bound + r.furniture_clearance_m
                        && (c - robot.goal).norm() >= bound + r.furniture_clearance_m;
                    if clear {
                        centres.push((c, bound));
                        shapes.push(rotated_box(c, hx, hy, angle));
                    }
                }
            }
            EnvKind::Pillars => {
                let p = &cfg.walls.pillars;
                let count = rng.gen_range(p.pillars_min..=p.pillars_max);
                let mut centres: Vec<Vec2> = Vec::new();
                let mut tries = 0;
                while centres.len() < count && tries < 1000 {
                    tries += 1;
                    let c = heading(uniform(rng, 0.0, std::f64::consts::TAU))
                        * (p.centre_radius_m * rng.gen::<f64>().sqrt());
                    if centres.iter().all(|o| (c - o).norm() >= p.spacing_m) {
                        centres.push(c);
                        let size = uniform(rng, p.size_min_m, p.size_max_m);
                        let angle = uniform(rng, 0.0, std::f64::consts::FRAC_PI_2);
                        shapes.push(if rng.gen::<bool>() {
                            rotated_box(c, size, size, angle)
                        } else {
                            regular(c, size, 8, angle)
                        });
                    }
                }
            }
            _ => unreachable!("drawn_map is called for the drawn layouts only"),
        }
        let map = StaticMap::new(shapes).map_err(|e| fail(e.to_string()))?;
        let reachable = map
            .reachable(robot.position, robot.goal, robot.radius_m, REACH_CELL_M)
            .map_err(|e| fail(e.to_string()))?;
        if reachable {
            return Ok(map);
        }
    }
    Err(fail(format!(
        "no layout with a reachable robot goal in {LAYOUT_ATTEMPTS} draws"
    )))
}

/// Which places of the people already placed a new place keeps clear of.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Clear {
    /// Their starts and their goals (people cross each other's ways: room, pillars).
    Both,
    /// Their starts only (a start in a lane: corridor, doorway).
    Starts,
    /// Their goals only (a goal in a lane).
    Goals,
}

/// A free place for a person of radius `r` on `map`, clear by `gap` of the `clear` places of
/// everybody `placed` (start, goal, radius), drawn by `draw`.
#[allow(clippy::too_many_arguments)]
fn place<R: Rng>(
    rng: &mut R,
    attempts: usize,
    map: &StaticMap,
    placed: &[(Vec2, Vec2, f64)],
    clear: Clear,
    r: f64,
    gap: f64,
    mut draw: impl FnMut(&mut R) -> Vec2,
) -> Option<Vec2> {
    (0..attempts).map(|_| draw(rng)).find(|&p| {
        map.is_free(p, r + gap)
            && placed.iter().all(|(s, g, pr)| {
                let min = r + pr + gap;
                (clear == Clear::Goals || (p - s).norm() >= min)
                    && (clear == Clear::Starts || (p - g).norm() >= min)
            })
    })
}

/// The scenario of a walled `setting` for `seed`.
pub(super) fn generate<R: Rng>(
    cfg: &SimConfig,
    setting: Setting,
    seed: u64,
    rng: &mut R,
) -> Result<Scenario, ScenarioError> {
    let robot = initial_robot(cfg);
    let h = &cfg.humans;
    let fail = |why: String| ScenarioError::Layout { setting, seed, why };
    let map = match fixed_map(cfg, setting.env) {
        Some(map) => map,
        None => drawn_map(cfg, setting, seed, rng)?,
    };
    let (r, gap) = (h.radius_m, h.spawn_gap_m);
    let too_crowded = |human: usize| ScenarioError::TooCrowded {
        setting,
        seed,
        human,
        attempts: h.max_spawn_attempts,
    };
    // People drawn one after the other can leave no room for the last in a lane: the whole
    // crowd is drawn again (from the same generator, so still a function of the seed).
    let draw_people = |rng: &mut R| -> Result<Vec<HumanState>, ScenarioError> {
        let mut placed = vec![(robot.position, robot.goal, robot.radius_m)];
        let mut humans = Vec::new();
        let people = match setting.env {
            EnvKind::Corridor => cfg.walls.corridor.people,
            EnvKind::Doorway => cfg.walls.doorway.people,
            EnvKind::Room => rng.gen_range(cfg.walls.room.people_min..=cfg.walls.room.people_max),
            EnvKind::Pillars => cfg.walls.pillars.people,
            _ => unreachable!("walled_layout::generate is called for walled settings only"),
        };
        for k in 0..people {
            let attempts = h.max_spawn_attempts;
            let (start, goal) = match setting.env {
                EnvKind::Corridor | EnvKind::Doorway => {
                    let (half_w, half_l) = match setting.env {
                        EnvKind::Corridor => (
                            cfg.walls.corridor.width_m / 2.0,
                            cfg.walls.corridor.length_m / 2.0,
                        ),
                        _ => (
                            cfg.walls.doorway.hall_width_m / 2.0,
                            cfg.walls.doorway.length_m / 2.0,
                        ),
                    };
                    let x_lim = (half_w - r - gap).max(0.0);
                    // Corridor: the first half come toward the robot; doorway: even people start
                    // on the robot's side (y < 0), odd ones on the far side.
                    let down = match setting.env {
                        EnvKind::Corridor => k < people / 2,
                        _ => k % 2 == 1,
                    };
                    let sign = if down { 1.0 } else { -1.0 };
                    let (y0, y1) = match setting.env {
                        EnvKind::Corridor => (0.5, half_l - 1.0),
                        _ => (1.0, half_l - 1.5),
                    };
                    let start = place(rng, attempts, &map, &placed, Clear::Starts, r, gap, |rng| {
                        Vec2::new(uniform(rng, -x_lim, x_lim), sign * uniform(rng, y0, y1))
                    })
                    .ok_or_else(|| too_crowded(k))?;
                    let goal = place(rng, attempts, &map, &placed, Clear::Goals, r, gap, |rng| {
                        Vec2::new(
                            uniform(rng, -x_lim, x_lim),
                            -sign * uniform(rng, half_l - 4.5, half_l - 0.5),
                        )
                    })
                    .ok_or_else(|| too_crowded(k))?;
                    (start, goal)
                }
                EnvKind::Room => {
                    let room = &cfg.walls.room;
                    let lim = room.side_m / 2.0 - r - gap;
                    let mut found = None;
                    for _ in 0..attempts {
                        let Some(start) =
                            place(rng, 1, &map, &placed, Clear::Both, r, gap, |rng| {
                                Vec2::new(uniform(rng, -lim, lim), uniform(rng, -lim, lim))
                            })
                        else {
                            continue;
                        };
                        let Some(goal) = place(rng, 1, &map, &placed, Clear::Both, r, gap, |rng| {
                            Vec2::new(uniform(rng, -lim, lim), uniform(rng, -lim, lim))
                        }) else {
                            continue;
                        };
                        if (goal - start).norm() >= room.min_trip_m
                            && map
                                .reachable(start, goal, r, REACH_CELL_M)
                                .map_err(|e| fail(e.to_string()))?
                        {
                            found = Some((start, goal));
                            break;
                        }
                    }
                    found.ok_or_else(|| too_crowded(k))?
                }
                EnvKind::Pillars => {
                    let start = place(rng, attempts, &map, &placed, Clear::Both, r, gap, |rng| {
                        let angle = rng.gen::<f64>() * std::f64::consts::TAU;
                        let noise = Vec2::new(
                            (rng.gen::<f64>() * 2.0 - 1.0) * h.start_noise_m,
                            (rng.gen::<f64>() * 2.0 - 1.0) * h.start_noise_m,
                        );
                        heading(angle) * h.circle_radius_m + noise
                    })
                    .ok_or_else(|| too_crowded(k))?;
                    (start, -start)
                }
                _ => unreachable!("walled_layout::generate is called for walled settings only"),
            };
            placed.push((start, goal, r));
            humans.push(HumanState {
                position: start,
                velocity: Vec2::zeros(),
                goal,
                radius_m: r,
                v_pref_mps: h.v_pref_mps,
                standing: false,
            });
        }
        Ok(humans)
    };
    let mut humans = draw_people(rng);
    for _ in 1..PEOPLE_ATTEMPTS {
        match humans {
            Err(ScenarioError::TooCrowded { .. }) => humans = draw_people(rng),
            _ => break,
        }
    }
    let humans = humans?;
    let walls = Walls::new(map, cfg, cfg.roadmap_radius_m()).map_err(|e| fail(e.to_string()))?;
    Ok(Scenario {
        robot,
        humans,
        walls: Some(Arc::new(walls)),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layouts_are_deterministic_and_keep_everybody_free() {
        use rand::SeedableRng;
        let cfg = SimConfig::default();
        for setting in Setting::WALLED {
            for seed in (0..200).chain([15479352932571408521]) {
                let mut a = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
                let mut b = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
                let s = generate(&cfg, setting, seed, &mut a).unwrap();
                assert_eq!(s, generate(&cfg, setting, seed, &mut b).unwrap());
                let walls = s.walls.as_ref().unwrap();
                assert!(walls.map().is_free(s.robot.position, s.robot.radius_m));
                assert!(walls.map().is_free(s.robot.goal, s.robot.radius_m));
                for h in &s.humans {
                    assert!(
                        walls.map().is_free(h.position, h.radius_m),
                        "{setting} {seed}"
                    );
                    assert!(walls.map().is_free(h.goal, h.radius_m), "{setting} {seed}");
                }
            }
        }
    }
}
