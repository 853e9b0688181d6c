//! Social-force people in fsrl's simulator (issue 54): ORCA stays the default and unchanged, the
//! env steps pysocialforce's model, a mixed crowd has its fraction, `visible_prob` hides the
//! robot, episodes replay from their seed, and bad config values are refused.

use sim::config::CrowdModel;
use sim::social_force::{psf_norm, Pedestrian, SocialForceSim};
use sim::{
    run_episode, Env, EnvError, Frame, HumanState, Outcome, RobotState, Scenario, Setting,
    SimConfig, Vec2,
};

fn with_model(model: CrowdModel) -> SimConfig {
    let mut cfg = SimConfig::default();
    cfg.humans.model = model;
    cfg
}

fn setting(name: &str) -> Setting {
    name.parse().unwrap()
}

/// The whole episode of `seed` with the ORCA robot, every frame recorded.
fn orca_robot_episode(cfg: &SimConfig, name: &str, seed: u64) -> (Outcome, Vec<Frame>) {
    let mut env = Env::new(cfg.clone(), setting(name), seed).unwrap();
    let ep = run_episode(&mut env, |env| env.orca_robot_action(0.0), true).unwrap();
    (ep.summary.outcome, ep.frames)
}

fn people_paths(frames: &[Frame]) -> Vec<Vec<Vec2>> {
    frames.iter().map(|f| f.humans.clone()).collect()
}

#[test]
fn default_config_serialises_as_before() {
    let text = toml::to_string(&SimConfig::default()).unwrap();
    for key in [
        "model",
        "social_force_fraction",
        "visible_prob",
        "social_force",
    ] {
        assert!(
            !text.contains(key),
            "`{key}` in the default config:\n{text}"
        );
    }
    // Set values are written and read back.
    let mut cfg = with_model(CrowdModel::Mixed);
    cfg.humans.social_force_fraction = 0.25;
    cfg.humans.visible_prob = 0.5;
    cfg.social_force.gamma = 0.4;
    let text = toml::to_string(&cfg).unwrap();
    assert!(text.contains("model = \"mixed\""), "{text}");
    assert!(text.contains("[social_force]"), "{text}");
    let back: SimConfig = toml::from_str(&text).unwrap();
    assert_eq!(back, cfg);
    // The keys as a user writes them.
    let cfg: SimConfig = toml::from_str(
        "[humans]\nmodel = \"social-force\"\nvisible_prob = 0.3\n\n[social_force]\nrelaxation_time_s = 0.4\n",
    )
    .unwrap();
    assert_eq!(cfg.humans.model, CrowdModel::SocialForce);
    assert_eq!(cfg.humans.visible_prob, 0.3);
    assert_eq!(cfg.social_force.relaxation_time_s, 0.4);
    assert_eq!(
        "social-force".parse::<CrowdModel>().unwrap(),
        CrowdModel::SocialForce
    );
}

/// A mixed crowd with no social-force person and everyone noticing the robot draws its people
/// from the seed but must give today's ORCA episode bit for bit: the scenario's random stream
/// and the ORCA step are untouched.
#[test]
fn a_crowd_with_no_social_force_person_is_todays_orca_crowd() {
    let mut mixed = with_model(CrowdModel::Mixed);
    mixed.humans.social_force_fraction = 0.0;
    let orca = SimConfig::default();
    for name in [
        "env1-invisible",
        "env2-visible",
        "env3-visible",
        "room-visible",
        "doorway",
    ] {
        for seed in [3, 1000, 20_017] {
            let env = Env::new(mixed.clone(), setting(name), seed).unwrap();
            assert!(env.social_force_humans().iter().all(|s| !s));
            assert_eq!(
                orca_robot_episode(&orca, name, seed),
                orca_robot_episode(&mixed, name, seed),
                "{name} seed {seed}"
            );
        }
    }
}

/// The env's social-force step is `SocialForceSim::step` (pysocialforce's, checked against the
/// reference data by `sf_ref.rs`) when fsrl's differences are set to psf's: Δt = 0.4 s and
/// `v_pref_mps` = 1.3 × the initial speed. Open floor, the robot visible: it is psf's last agent.
#[test]
fn the_env_steps_pysocialforce() {
    let mut cfg = with_model(CrowdModel::SocialForce);
    cfg.dt_s = 0.4;
    let start = [
        ([3.9, 0.3], [-0.8, 0.1], [-4.0, -0.2]),
        ([-3.7, 1.1], [0.9, -0.2], [3.8, -1.0]),
        ([0.4, 3.8], [0.05, -1.1], [-0.3, -4.0]),
        ([-0.6, -3.5], [0.1, 0.7], [0.5, 3.9]),
        ([2.2, 2.9], [-0.5, -0.6], [-2.0, -3.1]),
    ];
    let peds: Vec<Pedestrian> = start
        .iter()
        .map(|&(p, v, g)| Pedestrian {
            position: Vec2::new(p[0], p[1]),
            velocity: Vec2::new(v[0], v[1]),
            goal: Vec2::new(g[0], g[1]),
        })
        .collect();
    let humans: Vec<HumanState> = peds
        .iter()
        .map(|p| HumanState {
            position: p.position,
            velocity: p.velocity,
            goal: p.goal,
            radius_m: 0.3,
            v_pref_mps: 1.3 * psf_norm(p.velocity.x, p.velocity.y),
            standing: false,
        })
        .collect();
    let robot = RobotState {
        position: Vec2::new(0.2, -1.0),
        velocity: Vec2::new(0.0, 0.5),
        goal: Vec2::new(0.0, 4.0),
        heading_rad: std::f64::consts::FRAC_PI_2,
        radius_m: 0.3,
        v_pref_mps: 1.0,
    };
    let scenario = |humans: Vec<HumanState>| Scenario {
        robot,
        humans,
        walls: None,
    };
    let params = cfg.social_force.params(cfg.dt_s);

    // The robot visible: one step against psf with the robot as its last agent.
    let mut env = Env::from_scenario(
        cfg.clone(),
        setting("env1-visible"),
        7,
        scenario(humans.clone()),
    )
    .unwrap();
    let mut with_robot = peds.clone();
    with_robot.push(Pedestrian {
        position: robot.position,
        velocity: robot.velocity,
        goal: robot.goal,
    });
    let mut psf = SocialForceSim::new(params, &with_robot, &[], &[]).unwrap();
    psf.step().unwrap();
    let got = env.human_step_velocities().to_vec();
    for (k, v) in got.iter().enumerate() {
        assert_eq!(*v, psf.pedestrians()[k].velocity, "person {k}");
    }

    // The robot invisible: psf without it, over a free run (the robot stands far away).
    let mut far = scenario(humans);
    far.robot.position = Vec2::new(0.0, -30.0);
    far.robot.goal = Vec2::new(0.0, -25.0);
    let mut env = Env::from_scenario(cfg, setting("env1-invisible"), 7, far).unwrap();
    let mut psf = SocialForceSim::new(params, &peds, &[], &[]).unwrap();
    let mut moved = 0.0;
    for step in 0..40 {
        psf.step().unwrap();
        env.step(0).unwrap();
        for (k, (h, p)) in env.humans().iter().zip(psf.pedestrians()).enumerate() {
            assert_eq!(
                (h.position, h.velocity),
                (p.position, p.velocity),
                "step {step} person {k}"
            );
        }
        moved += env.humans()[0].velocity.norm();
    }
    assert!(moved > 5.0, "the people hardly moved: {moved}");
}

/// Social-force people start at rest (as fsrl's people do) and still walk, at their
/// `v_pref_mps`, to within psf's arrive radius of their goals, and stay there.
#[test]
fn social_force_people_walk_to_their_goals() {
    let mut cfg = with_model(CrowdModel::SocialForce);
    cfg.time_limit_s = 60.0;
    // The robot waits far from the crowd.
    cfg.robot.start_m = [0.0, -30.0];
    cfg.robot.goal_m = [0.0, -20.0];
    let arrive = cfg.social_force.arrive_radius_m;
    for seed in 0..10 {
        let mut env = Env::new(cfg.clone(), setting("env2-visible"), seed).unwrap();
        assert!(env.social_force_humans().iter().all(|&s| s));
        let start: Vec<HumanState> = env.humans().to_vec();
        let mut top_speed: f64 = 0.0;
        for _ in 0..120 {
            env.step(0).unwrap();
            for h in env.humans() {
                top_speed = top_speed.max(h.velocity.norm());
                assert!(h.velocity.norm() <= h.v_pref_mps + 1e-12);
            }
        }
        assert!(
            top_speed > 0.95 * cfg.humans.v_pref_mps,
            "seed {seed}: {top_speed}"
        );
        for (k, (h, h0)) in env.humans().iter().zip(&start).enumerate() {
            if h.standing {
                assert_eq!(h.position, h0.position, "seed {seed}: standing {k} moved");
                continue;
            }
            let left = (h.position - h.goal).norm();
            assert!(
                left < arrive,
                "seed {seed}: person {k} is {left} m from its goal"
            );
            assert_eq!(h.velocity, Vec2::zeros(), "seed {seed}: person {k}");
        }
    }
}

/// With the ORCA robot, social-force episodes run to their end in every setting, walled ones
/// included, and nobody leaves the walls' free space.
#[test]
fn social_force_episodes_run_to_their_end() {
    let cfg = with_model(CrowdModel::SocialForce);
    for name in [
        "env1-visible",
        "env2-invisible",
        "env3-visible",
        "corridor",
        "doorway",
        "room-visible",
        "pillars-invisible",
    ] {
        let mut outcomes = [0usize; 3];
        let mut clearance = f64::INFINITY;
        for seed in 0..20 {
            let mut env = Env::new(cfg.clone(), setting(name), seed).unwrap();
            let start: Vec<Vec2> = env.humans().iter().map(|h| h.position).collect();
            let ep = run_episode(&mut env, |env| env.orca_robot_action(0.0), true).unwrap();
            let k = match ep.summary.outcome {
                Outcome::ReachGoal => 0,
                Outcome::Collision => 1,
                Outcome::Timeout => 2,
                Outcome::Running => panic!("{name} seed {seed} did not end"),
            };
            outcomes[k] += 1;
            let walked: f64 = env
                .humans()
                .iter()
                .zip(&start)
                .map(|(h, s)| (h.position - s).norm())
                .sum();
            assert!(walked > 1.0, "{name} seed {seed}: people walked {walked} m");
            if let Some(map) = env.wall_map() {
                for f in &ep.frames {
                    for p in &f.humans {
                        assert!(map.is_free(*p, 0.0), "{name} seed {seed}: {p:?} in a wall");
                        clearance = clearance.min(map.distance_m(*p));
                    }
                }
            }
        }
        println!("{name}: success/collision/timeout {outcomes:?}, people's least clearance from the walls {clearance:.3} m");
    }
}

/// Each person is social-force with probability `social_force_fraction` and notices the robot
/// with probability `visible_prob`, independently.
#[test]
fn a_mixed_crowd_has_its_fraction() {
    for (fraction, visible) in [(0.3, 1.0), (0.7, 0.4)] {
        let mut cfg = with_model(CrowdModel::Mixed);
        cfg.humans.social_force_fraction = fraction;
        cfg.humans.visible_prob = visible;
        let mut env = Env::new(cfg.clone(), setting("env1-visible"), 0).unwrap();
        let (mut people, mut social, mut noticing, mut both) = (0usize, 0usize, 0usize, 0usize);
        let mut crowds = std::collections::HashSet::new();
        for seed in 0..500 {
            env.reset(seed).unwrap();
            people += env.humans().len();
            for (&s, &n) in env
                .social_force_humans()
                .iter()
                .zip(env.humans_noticing_robot())
            {
                social += s as usize;
                noticing += n as usize;
                both += (s && n) as usize;
            }
            crowds.insert(env.social_force_humans().to_vec());
        }
        let p = people as f64;
        // Five standard deviations of a binomial over 5000 people: about 0.033.
        let near = |got: usize, want: f64| {
            let sd = (want * (1.0 - want) / p).sqrt();
            (got as f64 / p - want).abs() <= 5.0 * sd.max(1e-9)
        };
        assert!(
            near(social, fraction),
            "{social} of {people} for {fraction}"
        );
        assert!(
            near(noticing, visible),
            "{noticing} of {people} for {visible}"
        );
        assert!(near(both, fraction * visible), "{both} of {people}");
        // Ten people give 1024 possible crowds, the likely ones far more often: a model drawn
        // per episode rather than once gives far more than 150 different ones in 500 seeds.
        assert!(crowds.len() > 150, "only {} different crowds", crowds.len());
    }
    // The ends of the range are exact.
    for (fraction, all) in [(0.0, false), (1.0, true)] {
        let mut cfg = with_model(CrowdModel::Mixed);
        cfg.humans.social_force_fraction = fraction;
        for seed in 0..50 {
            let env = Env::new(cfg.clone(), setting("env2-visible"), seed).unwrap();
            assert!(env.social_force_humans().iter().all(|&s| s == all));
            assert!(env.humans_noticing_robot().iter().all(|&n| n));
        }
    }
}

/// People who do not notice the robot move as everyone does in the invisible setting; the
/// control (everyone noticing) differs, so the comparison can tell.
#[test]
fn unnoticed_robot_is_an_invisible_robot() {
    for model in [CrowdModel::Orca, CrowdModel::SocialForce] {
        let noticed = with_model(model);
        let mut unnoticed = with_model(model);
        unnoticed.humans.visible_prob = 0.0;
        let mut differ = 0;
        for seed in 0..8 {
            let hidden = orca_robot_episode(&unnoticed, "env1-visible", seed);
            let invisible = orca_robot_episode(&noticed, "env1-invisible", seed);
            assert_eq!(
                people_paths(&hidden.1),
                people_paths(&invisible.1),
                "{model} seed {seed}"
            );
            assert_eq!(hidden, invisible, "{model} seed {seed}");
            let visible = orca_robot_episode(&noticed, "env1-visible", seed);
            differ += (people_paths(&visible.1) != people_paths(&invisible.1)) as usize;
        }
        assert!(
            differ >= 6,
            "{model}: the robot changed only {differ} of 8 crowds"
        );
    }
}

#[test]
fn the_same_seed_gives_the_same_episode() {
    let mut cfg = with_model(CrowdModel::Mixed);
    cfg.humans.visible_prob = 0.5;
    for name in ["env2-visible", "room-visible"] {
        let mut reused = Env::new(cfg.clone(), setting(name), 99).unwrap();
        let mut crowds = Vec::new();
        for seed in [11, 12] {
            let a = orca_robot_episode(&cfg, name, seed);
            let b = orca_robot_episode(&cfg, name, seed);
            assert_eq!(a, b, "{name} seed {seed}");
            // A reset env replays it too (its buffers and draws are renewed).
            reused.reset(seed).unwrap();
            let draws = (
                reused.social_force_humans().to_vec(),
                reused.humans_noticing_robot().to_vec(),
            );
            let ep = run_episode(&mut reused, |env| env.orca_robot_action(0.0), true).unwrap();
            assert_eq!((ep.summary.outcome, ep.frames), a, "{name} seed {seed}");
            crowds.push((draws, a));
        }
        assert_ne!(
            crowds[0], crowds[1],
            "{name}: seeds 11 and 12 gave one episode"
        );
    }
}

/// A change that makes a config invalid.
type Spoil = fn(&mut SimConfig);

#[test]
fn bad_values_are_refused_with_their_message() {
    let cases: [(&str, Spoil); 9] = [
        ("humans.visible_prob must be a probability in [0, 1], got 1.5", |c| {
            c.humans.visible_prob = 1.5
        }),
        ("humans.visible_prob must be a finite number", |c| {
            c.humans.visible_prob = f64::NAN
        }),
        (
            "humans.social_force_fraction must be a probability in [0, 1], got -0.1",
            |c| {
                c.humans.model = CrowdModel::Mixed;
                c.humans.social_force_fraction = -0.1
            },
        ),
        (
            "humans.social_force_fraction (0.2) is read only with humans.model = \"mixed\"; humans.model is \"social-force\"",
            |c| {
                c.humans.model = CrowdModel::SocialForce;
                c.humans.social_force_fraction = 0.2
            },
        ),
        ("social_force.relaxation_time_s must be > 0, got 0", |c| {
            c.social_force.relaxation_time_s = 0.0
        }),
        ("social_force.gamma must be > 0, got -0.35", |c| {
            c.social_force.gamma = -0.35
        }),
        ("social_force.obstacle_sigma_m must be a finite number", |c| {
            c.social_force.obstacle_sigma_m = f64::INFINITY
        }),
        ("social_force.resolution_per_m must be at most 1000", |c| {
            c.social_force.resolution_per_m = 1e6
        }),
        ("social_force.arrive_radius_m must be >= 0, got -0.5", |c| {
            c.social_force.arrive_radius_m = -0.5
        }),
    ];
    for (want, spoil) in cases {
        let mut cfg = SimConfig::default();
        spoil(&mut cfg);
        let err = Env::new(cfg, setting("env1-visible"), 0).unwrap_err();
        assert!(matches!(err, EnvError::Config(_)), "{err}");
        let text = err.to_string();
        assert!(text.contains(want), "missing {want:?} in\n{text}");
    }
    // Unknown keys and model names are refused by the parser.
    for (toml_text, want) in [
        ("[humans]\nmodel = \"sf\"\n", "unknown variant `sf`"),
        (
            "[social_force]\nrelaxation_s = 0.5\n",
            "unknown field `relaxation_s`",
        ),
    ] {
        let err = toml::from_str::<SimConfig>(toml_text)
            .unwrap_err()
            .to_string();
        assert!(err.contains(want), "missing {want:?} in\n{err}");
    }
    let err = "sf".parse::<CrowdModel>().unwrap_err().to_string();
    assert!(
        err.contains("expected one of orca, social-force, mixed"),
        "{err}"
    );
}
