//! `train.select`: which weights of a run are its trained policy. With `best-validation`,
//! `fsrl train --single-process` keeps every validation's weights as a model file
//! (`checkpoints/validation/ep-<RL episodes>.fsrlm`, written before its `metrics.jsonl` line),
//! and the run's policy (final evaluation, `fsrl export-model RUN`, `fsrl eval RUN`) is the
//! snapshot whose validation scored best. Only validation seeds take part in the choice.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use policy::method::Select;

use crate::config::FileConfig;

/// Why a distributed run cannot take this training config, if it cannot: there the evaluator
/// process validates and keeps no weights, so only single-process training selects.
pub fn distributed_problem(train: &policy::method::TrainConfig) -> Option<String> {
    (train.select == Select::BestValidation).then(|| {
        "train.select = \"best-validation\" needs single-process training (`fsrl train --single-process`, `fsrl reproduce`): in a distributed run the evaluator validates and keeps no weights".to_string()
    })
}

/// The directory of a run's validation snapshots.
pub fn snapshot_dir(run_dir: &Path) -> PathBuf {
    run_dir.join("checkpoints").join("validation")
}

/// The snapshot file of the validation after `rl_episodes` RL episodes.
pub fn snapshot_path(run_dir: &Path, rl_episodes: u64) -> PathBuf {
    snapshot_dir(run_dir).join(format!("ep-{rl_episodes:06}.fsrlm"))
}

/// One validation of a run, as its `metrics.jsonl` line records it.
#[derive(Debug, Clone, PartialEq)]
pub struct Validation {
    pub rl_episodes: u64,
    pub success: f64,
    pub collision: f64,
}

/// The validations of a metrics log, one per RL episode count: a resumed run validates the
/// episodes after its checkpoint again, and the later line is the one of the surviving run.
pub fn validations(metrics_jsonl: &str) -> Vec<Validation> {
    let mut by_episode = BTreeMap::new();
    for v in metrics_jsonl
        .lines()
        .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
        .filter(|v| v.get("phase").and_then(|p| p.as_str()) == Some("validation"))
    {
        let num = |k: &str| v.get(k).and_then(|x| x.as_f64()).filter(|x| x.is_finite());
        let (Some(ep), Some(success), Some(collision)) = (
            v.get("episode").and_then(|x| x.as_u64()),
            num("success_rate"),
            num("collision_rate"),
        ) else {
            continue;
        };
        by_episode.insert(
            ep,
            Validation {
                rl_episodes: ep,
                success,
                collision,
            },
        );
    }
    by_episode.into_values().collect()
}

/// The best of `candidates`: highest success, then fewest collisions, then the earliest.
pub fn best(candidates: impl IntoIterator<Item = Validation>) -> Option<Validation> {
    candidates.into_iter().fold(None, |acc, v| match acc {
        Some(b) if (v.success, -v.collision) <= (b.success, -b.collision) => Some(b),
        _ => Some(v),
    })
}

/// The best validation of a run that has its snapshot on disk, with the snapshot's path.
pub fn best_snapshot(run_dir: &Path) -> anyhow::Result<Option<(Validation, PathBuf)>> {
    let path = run_dir.join("metrics.jsonl");
    let text = std::fs::read_to_string(&path)
        .with_context(|| format!("cannot read {}", path.display()))?;
    let found = best(
        validations(&text)
            .into_iter()
            .filter(|v| snapshot_path(run_dir, v.rl_episodes).exists()),
    );
    Ok(found.map(|v| {
        let p = snapshot_path(run_dir, v.rl_episodes);
        (v, p)
    }))
}

/// The policy file of a run directory: its `checkpoints/latest.ckpt`, or with
/// `train.select = "best-validation"` in its `config.toml` the best validation snapshot.
pub fn run_policy(run_dir: &Path) -> anyhow::Result<PathBuf> {
    let latest = run_dir.join("checkpoints").join("latest.ckpt");
    let select = FileConfig::load(Some(&run_dir.join("config.toml")))
        .map(|c| c.train.select)
        .unwrap_or_default();
    if select == Select::Last {
        return Ok(latest);
    }
    match best_snapshot(run_dir)? {
        Some((v, path)) => {
            eprintln!(
                "{}: train.select = \"best-validation\": the snapshot after {} RL episodes (validation success {:.2}, collision {:.2})",
                run_dir.display(),
                v.rl_episodes,
                v.success,
                v.collision
            );
            Ok(path)
        }
        None => bail!(
            "{}: train.select = \"best-validation\" but no validation snapshot in {} matches a validation line of metrics.jsonl",
            run_dir.display(),
            snapshot_dir(run_dir).display()
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
        ]
        .concat();
        let v = validations(&text);
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
        // Without the switch: the last weights.
        std::fs::write(run.join("config.toml"), "").unwrap();
        assert_eq!(
            run_policy(run).unwrap(),
            run.join("checkpoints").join("latest.ckpt")
        );
        std::fs::write(
            run.join("config.toml"),
            "[train]\nselect = \"best-validation\"\n",
        )
        .unwrap();
        let err = run_policy(run).unwrap_err().to_string();
        assert!(err.contains("no validation snapshot"), "{err}");
        // The best validation's snapshot is missing (never written): the best one on disk.
        for ep in [0, 200] {
            std::fs::write(snapshot_path(run, ep), b"x").unwrap();
        }
        assert_eq!(run_policy(run).unwrap(), snapshot_path(run, 200));
        std::fs::write(snapshot_path(run, 100), b"x").unwrap();
        assert_eq!(run_policy(run).unwrap(), snapshot_path(run, 100));
    }
}
