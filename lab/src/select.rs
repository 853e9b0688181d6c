//! `train.select`: which weights of a run are its trained policy. With `best-validation` or
//! `low-disc` every validation's weights are kept as a model file
//! (`checkpoints/validation/ep-<RL episodes>.fsrlm`, written before its validation line: by the
//! trainer in `fsrl train --single-process`, by the evaluator process in a distributed run),
//! and the run's policy (final evaluation, `fsrl export-model RUN`, `fsrl eval RUN`) is the
//! snapshot the rule chooses: the best validation success, or the lowest validation Disc. among
//! the good validations after the ε decay, or the highest return, or (`revalidated-return`,
//! [`crate::revalidation`]) the best of the highest returns re-validated on fresh validation
//! seeds. Only validation seeds take part in the choice; a snapshot file that does not load
//! (damaged, cut short) is reported and never chosen.

use std::collections::BTreeMap;

use policy::method::{Select, LOW_DISC_MIN_SUCCESS};

pub use learner::model::{snapshot_dir, snapshot_path};

/// One validation of a run, as its `metrics.jsonl` line records it.
#[derive(Debug, Clone, PartialEq)]
pub struct Validation {
    pub rl_episodes: u64,
    pub success: f64,
    pub collision: f64,
    /// Disc. on the validation episodes (`discomfort`); absent in old logs.
    pub disc: Option<f64>,
    /// Mean Nav. Time (s) of the successful validation episodes (`nav_time_s`); absent in old
    /// logs and without a success.
    pub nav_time_s: Option<f64>,
    /// Mean return of the validation episodes (`mean_return`); absent in old logs.
    pub mean_return: Option<f64>,
}

/// The validations of a metrics log, one per RL episode count: a resumed run validates the
/// episodes after its checkpoint again, and the later line is the one of the surviving run.
/// Also returns how many lines were skipped: not JSON (a line cut short by a crash is one),
/// validation lines without a success or collision rate, or with a value no validation can have
/// (a rate outside [0, 1], a Nav. Time not positive, anything not finite): a hand-edited or
/// corrupted log must not ship a snapshot on a Disc. of −1. Callers say so.
pub fn validations(metrics_jsonl: &str) -> (Vec<Validation>, usize) {
    let mut by_episode = BTreeMap::new();
    let mut skipped = 0;
    for l in metrics_jsonl.lines().filter(|l| !l.trim().is_empty()) {
        let Ok(v) = serde_json::from_str::<serde_json::Value>(l) else {
            skipped += 1;
            continue;
        };
        if v.get("phase").and_then(|p| p.as_str()) != Some("validation") {
            continue;
        }
        let num = |k: &str| v.get(k).and_then(|x| x.as_f64());
        let rate = |x: f64| (0.0..=1.0).contains(&x);
        let (Some(ep), Some(success), Some(collision)) = (
            v.get("episode").and_then(|x| x.as_u64()),
            num("success_rate"),
            num("collision_rate"),
        ) else {
            skipped += 1;
            continue;
        };
        let (disc, nav_time_s) = (num("discomfort"), num("nav_time_s"));
        let mean_return = num("mean_return");
        let valid = rate(success)
            && rate(collision)
            && disc.is_none_or(rate)
            && nav_time_s.is_none_or(|t| t.is_finite() && t > 0.0)
            && mean_return.is_none_or(f64::is_finite);
        if !valid {
            skipped += 1;
            continue;
        }
        by_episode.insert(
            ep,
            Validation {
                rl_episodes: ep,
                success,
                collision,
                disc,
                nav_time_s,
                mean_return,
            },
        );
    }
    (by_episode.into_values().collect(), skipped)
}

/// The best of `candidates`: highest success, then fewest collisions, then the earliest.
pub fn best(candidates: impl IntoIterator<Item = Validation>) -> Option<Validation> {
    candidates.into_iter().fold(None, |acc, v| match acc {
        Some(b) if (v.success, -v.collision) <= (b.success, -b.collision) => Some(b),
        _ => Some(v),
    })
}

/// Whether `v` is a good validation: after `from_episode` RL episodes (the end of the ε decay)
/// with validation success at least `min_success` ([`Select::LowDisc`] chooses among those at
/// [`LOW_DISC_MIN_SUCCESS`]).
pub fn good_after(v: &Validation, from_episode: u64, min_success: f64) -> bool {
    v.rl_episodes >= from_episode && v.success >= min_success
}

/// [`Select::LowDisc`]: among the validations after `from_episode` RL episodes with success at
/// least [`LOW_DISC_MIN_SUCCESS`], the lowest Disc. (ties: the later); without one, [`best`].
pub fn low_disc(
    candidates: impl IntoIterator<Item = Validation>,
    from_episode: u64,
) -> Option<Validation> {
    highest_later(candidates, |v| {
        good_after(v, from_episode, LOW_DISC_MIN_SUCCESS)
            .then_some(v.disc)
            .flatten()
            .map(|d| -d)
    })
}

/// The candidate with the highest `key` (ties: the later; `None`: not a candidate); without
/// one, [`best`] of them all. [`low_disc`] and [`best_return`] both choose this way.
fn highest_later(
    candidates: impl IntoIterator<Item = Validation>,
    key: impl Fn(&Validation) -> Option<f64>,
) -> Option<Validation> {
    let all: Vec<Validation> = candidates.into_iter().collect();
    let top = all.iter().filter_map(|v| key(v).map(|k| (k, v))).fold(
        None::<(f64, &Validation)>,
        |acc, (k, v)| match acc {
            Some((bk, _)) if k < bk => acc,
            _ => Some((k, v)),
        },
    );
    match top {
        Some((_, v)) => Some(v.clone()),
        None => best(all),
    }
}

/// [`Select::BestReturn`]: among the validations after `from_episode` RL episodes, the highest
/// mean return (ties: the later); without one that has a return, [`best`].
pub fn best_return(
    candidates: impl IntoIterator<Item = Validation>,
    from_episode: u64,
) -> Option<Validation> {
    highest_later(candidates, |v| {
        (v.rl_episodes >= from_episode)
            .then_some(v.mean_return)
            .flatten()
    })
}

/// The validation `rule` chooses among `candidates` (`None` for [`Select::Last`]). From the
/// validations alone [`Select::RevalidatedReturn`] can only say what [`best_return`] says (its
/// first candidate); its choice is [`crate::revalidation::choose`]'s, which scores again.
pub fn choose(
    rule: Select,
    candidates: impl IntoIterator<Item = Validation>,
    decay_end_episode: u64,
) -> Option<Validation> {
    match rule {
        Select::Last => None,
        Select::BestValidation => best(candidates),
        Select::LowDisc => low_disc(candidates, decay_end_episode),
        Select::BestReturn | Select::RevalidatedReturn => {
            best_return(candidates, decay_end_episode)
        }
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::policy_choice::run_policy;
    use std::path::Path;

    /// A real (loadable) snapshot file: a fresh SARL network's model.
    pub(crate) fn snapshot(path: &Path) {
        use std::sync::OnceLock;
        static BYTES: OnceLock<Vec<u8>> = OnceLock::new();
        let bytes = BYTES.get_or_init(|| {
            let sim = sim::SimConfig::default();
            let train = policy::method::TrainConfig::default();
            let core = learner::LearnerCore::new(
                policy::method::Method::Sarl,
                train,
                sim.humans.count,
                sim.dt_s,
                0,
            )
            .unwrap();
            let run = learner::checkpoint::RunInfo {
                run_id: "unit".into(),
                setting: "env1-invisible".into(),
                run_seed: 0,
                accepted_below: Default::default(),
            };
            let dir = tempfile::tempdir().unwrap();
            let p = dir.path().join("m.fsrlm");
            learner::model::Model::from_core(&core, &sim, &run)
                .unwrap()
                .save(&p)
                .unwrap();
            std::fs::read(&p).unwrap()
        });
        std::fs::write(path, bytes).unwrap();
    }

    fn line(ep: u64, success: f64, collision: f64) -> String {
        format!(
            "{{\"phase\":\"validation\",\"episode\":{ep},\"success_rate\":{success},\"collision_rate\":{collision},\"timeout_rate\":0.0}}\n"
        )
    }

    #[test]
    fn the_later_line_of_a_repeated_validation_wins() {
        let text = [
            line(100, 0.5, 0.1),
            "{\"phase\":\"rl\",\"episode\":3}\n".into(),
            line(200, 0.9, 0.0),
            // Resumed from the checkpoint at 100: the run's own validation at 200.
            line(200, 0.4, 0.3),
            "not json\n".into(),
            "{\"phase\":\"validation\",\"episode\":300}\n".into(),
            // Values no validation has: each line skipped, none replaces the one at 200.
            line(200, 1.5, 0.0),
            line(200, 0.9, -0.1),
            "{\"phase\":\"validation\",\"episode\":200,\"success_rate\":1.0,\"collision_rate\":0.0,\"discomfort\":-1.0}\n".into(),
            "{\"phase\":\"validation\",\"episode\":200,\"success_rate\":1.0,\"collision_rate\":0.0,\"nav_time_s\":0.0}\n".into(),
            "{\"phase\":\"validation\",\"episode\":200,\"success_rate\":1.0,\"collision_rate\":0.0,\"nav_time_s\":1e400}\n".into(),
        ]
        .concat();
        let (v, skipped) = validations(&text);
        // "not json", the validation line without rates and the five impossible ones.
        assert_eq!(skipped, 7);
        assert_eq!(v.len(), 2);
        assert_eq!(v[1].rl_episodes, 200);
        assert_eq!(v[1].success, 0.4);
    }

    #[test]
    fn best_is_success_then_fewer_collisions_then_earlier() {
        let v = |ep, s, c| Validation {
            rl_episodes: ep,
            success: s,
            collision: c,
            disc: None,
            nav_time_s: None,
            mean_return: None,
        };
        let got = best([
            v(100, 0.6, 0.2),
            v(200, 0.8, 0.2),
            v(300, 0.8, 0.1),
            v(400, 0.8, 0.1),
        ]);
        assert_eq!(got.unwrap().rl_episodes, 300);
        assert_eq!(best([]), None);
    }

    #[test]
    fn a_run_directory_resolves_to_the_selected_policy() {
        let dir = tempfile::tempdir().unwrap();
        let run = dir.path();
        std::fs::create_dir_all(snapshot_dir(run)).unwrap();
        std::fs::write(
            run.join("metrics.jsonl"),
            [line(0, 0.1, 0.5), line(100, 0.9, 0.0), line(200, 0.7, 0.0)].concat(),
        )
        .unwrap();
        // The last weights.
        std::fs::write(run.join("config.toml"), "[train]\nselect = \"last\"\n").unwrap();
        assert_eq!(
            run_policy(run, None).unwrap(),
            run.join("checkpoints").join("latest.ckpt")
        );
        std::fs::write(
            run.join("config.toml"),
            "[train]\nselect = \"best-validation\"\n",
        )
        .unwrap();
        let err = run_policy(run, None).unwrap_err().to_string();
        assert!(err.contains("no validation snapshot"), "{err}");
        // The best validation's snapshot is missing (never written): the best one on disk.
        for ep in [0, 200] {
            snapshot(&snapshot_path(run, ep));
        }
        assert_eq!(run_policy(run, None).unwrap(), snapshot_path(run, 200));
        // A damaged snapshot of the best validation is skipped, never chosen.
        std::fs::write(snapshot_path(run, 100), b"x").unwrap();
        assert_eq!(run_policy(run, None).unwrap(), snapshot_path(run, 200));
        snapshot(&snapshot_path(run, 100));
        assert_eq!(run_policy(run, None).unwrap(), snapshot_path(run, 100));
        // A distributed run's evaluator writes validation.jsonl first: its lines count too.
        std::fs::write(run.join("validation.jsonl"), [line(300, 1.0, 0.0)].concat()).unwrap();
        snapshot(&snapshot_path(run, 300));
        assert_eq!(run_policy(run, None).unwrap(), snapshot_path(run, 300));
        std::fs::remove_file(run.join("validation.jsonl")).unwrap();
        // A rule given on the command line overrides the run's own.
        assert_eq!(
            run_policy(run, Some(Select::Last)).unwrap(),
            run.join("checkpoints").join("latest.ckpt")
        );
    }

    #[test]
    fn low_disc_is_the_gentlest_good_validation_after_the_decay() {
        let v = |ep, s, d| Validation {
            rl_episodes: ep,
            success: s,
            collision: 1.0 - s,
            disc: Some(d),
            nav_time_s: Some(12.0),
            mean_return: None,
        };
        let runs = [
            v(1000, 0.99, 0.01), // before the decay ends: not a candidate
            v(2000, 0.96, 0.05),
            v(2250, 0.94, 0.02), // below 0.95
            v(2500, 1.00, 0.07),
            v(2750, 0.95, 0.05), // ties with 2000: the later wins
            v(3000, 0.98, 0.06),
        ];
        assert_eq!(low_disc(runs.clone(), 2000).unwrap().rl_episodes, 2750);
        // Without a good validation after the decay: the best success.
        let weak = [
            v(2000, 0.90, 0.01),
            v(2500, 0.93, 0.09),
            v(3000, 0.91, 0.02),
        ];
        assert_eq!(low_disc(weak, 2000).unwrap().rl_episodes, 2500);
        // Old logs without Disc.: the best success, too.
        let old = [
            Validation {
                disc: None,
                ..v(2500, 0.97, 0.0)
            },
            Validation {
                disc: None,
                ..v(3000, 0.99, 0.0)
            },
        ];
        assert_eq!(low_disc(old, 0).unwrap().rl_episodes, 3000);
        assert_eq!(low_disc([], 0), None);
    }

    #[test]
    fn a_low_disc_run_reads_its_decay_from_its_config() {
        let dir = tempfile::tempdir().unwrap();
        let run = dir.path();
        std::fs::create_dir_all(snapshot_dir(run)).unwrap();
        let line = |ep: u64, s: f64, d: f64| {
            format!(
                "{{\"phase\":\"validation\",\"episode\":{ep},\"success_rate\":{s},\"collision_rate\":0.0,\"discomfort\":{d}}}\n"
            )
        };
        std::fs::write(
            run.join("metrics.jsonl"),
            [
                line(100, 1.0, 0.01),
                line(300, 0.96, 0.04),
                line(400, 0.97, 0.08),
            ]
            .concat(),
        )
        .unwrap();
        for ep in [100, 300, 400] {
            snapshot(&snapshot_path(run, ep));
        }
        std::fs::write(
            run.join("config.toml"),
            "[train]\nselect = \"low-disc\"\n[train.rl]\nepsilon_decay_episodes = 200\n",
        )
        .unwrap();
        assert_eq!(run_policy(run, None).unwrap(), snapshot_path(run, 300));
        assert_eq!(
            run_policy(run, Some(Select::BestValidation)).unwrap(),
            snapshot_path(run, 100)
        );
    }

    /// `best-return` takes the highest validation return after the ε decay (ties: the later),
    /// whatever the success or Disc.; before the decay nothing counts; without returns (old
    /// logs) it is `best`. Fails when the rule is ignored: `low-disc` and `best` choose other
    /// validations here.
    #[test]
    fn best_return_is_the_highest_validation_return_after_the_decay() {
        let v = |ep, s, d, r| Validation {
            rl_episodes: ep,
            success: s,
            collision: 1.0 - s,
            disc: Some(d),
            nav_time_s: Some(12.0),
            mean_return: Some(r),
        };
        let runs = [
            v(1000, 1.00, 0.01, 0.99), // before the decay ends: not a candidate
            v(2000, 1.00, 0.02, 0.90), // the gentlest and first at 1.00
            v(2500, 0.98, 0.05, 0.93),
            v(3000, 0.99, 0.04, 0.93), // ties with 2500: the later wins
            v(3500, 0.97, 0.06, 0.91),
        ];
        let got = |rule| choose(rule, runs.clone(), 2000).map(|c| c.rl_episodes);
        assert_eq!(got(Select::BestReturn), Some(3000));
        assert_eq!(got(Select::LowDisc), Some(2000));
        assert_eq!(got(Select::BestValidation), Some(1000));
        let old = runs.map(|r| Validation {
            mean_return: None,
            ..r
        });
        assert_eq!(best_return(old, 2000).unwrap().rl_episodes, 1000);
        assert_eq!(best_return([], 0), None);
        // A return that is not a number makes the line unreadable, never chosen.
        let (read, skipped) = validations(
            r#"{"phase":"validation","episode":2000,"success_rate":1.0,"collision_rate":0.0,"mean_return":1e999}"#,
        );
        assert!(read.is_empty() && skipped == 1, "{read:?}");
    }
}
