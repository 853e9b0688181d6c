//! The policy of a run directory: the validation snapshot its `train.select` chooses (with
//! `revalidated-return`, after re-validating its candidates) or its last checkpoint, and the
//! policy file a command is given ([`resolve_input`]). Above `select`, `revalidation`,
//! `evaluation` and `policy_file`, which it uses: none of them looks up here.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use policy::method::Select;

use crate::policy_file::Input;
use crate::revalidation::{Plan, Scorer};
use crate::run::RunFile;
use crate::select::{choose, snapshot_dir, snapshot_path, validations, Validation};

/// A run directory means its `checkpoints/latest.ckpt` or the validation snapshot its
/// `train.select` (or `select`, when given) chooses; anything else is a model file or a
/// checkpoint.
pub fn resolve_input(path: &Path, select: Option<Select>) -> anyhow::Result<Input> {
    if path.is_dir() {
        if !path.join("checkpoints").join("latest.ckpt").exists() {
            bail!(
                "{}: a directory without checkpoints/latest.ckpt (not a run directory of `fsrl train`)",
                path.display()
            );
        }
        Ok(Input {
            checkpoint: run_policy(path, select)?,
            run_dir: Some(path.to_path_buf()),
        })
    } else if path.exists() {
        Ok(Input {
            checkpoint: path.to_path_buf(),
            run_dir: None,
        })
    } else {
        bail!("{}: no such checkpoint or run directory", path.display())
    }
}

/// The validation `rule` chooses among a run's validations that have their snapshot on disk,
/// with the snapshot's path; `None` for [`Select::Last`] or without a snapshot.
/// [`Select::RevalidatedReturn`] re-validates its candidates as `how` says, each with `score`
/// ([`crate::revalidation::choose`]).
pub fn chosen_snapshot(
    run_dir: &Path,
    rule: Select,
    decay_end_episode: u64,
    how: &Plan,
    score: &mut Scorer<'_>,
) -> anyhow::Result<Option<(Validation, PathBuf)>> {
    let path = run_dir.join("metrics.jsonl");
    let mut text = std::fs::read_to_string(&path)
        .with_context(|| format!("cannot read {}", path.display()))?;
    // A distributed run's evaluator writes its validation lines here first (the launcher copies
    // them into metrics.jsonl when the run ends): a running or interrupted run is chosen from
    // too. The same line twice is one validation.
    if let Ok(extra) = std::fs::read_to_string(run_dir.join("validation.jsonl")) {
        text.push('\n');
        text.push_str(&extra);
    }
    let (all, skipped) = validations(&text);
    if skipped > 0 {
        tracing::warn!(
            "{}: {skipped} unreadable or impossible line(s) skipped while choosing the snapshot",
            path.display()
        );
    }
    let on_disk = all.into_iter().filter(|v| {
        let p = snapshot_path(run_dir, v.rl_episodes);
        if !p.exists() {
            return false;
        }
        match learner::model::Model::load(&p) {
            Ok(_) => true,
            Err(e) => {
                eprintln!("warning: skipping a damaged snapshot (never chosen): {e}");
                false
            }
        }
    });
    let found = if rule == Select::RevalidatedReturn {
        let on_disk: Vec<Validation> = on_disk.collect();
        crate::revalidation::choose(run_dir, &on_disk, decay_end_episode, how, score)?
            .map(|(v, _)| v)
    } else {
        choose(rule, on_disk, decay_end_episode)
    };
    Ok(found.map(|v| {
        let p = snapshot_path(run_dir, v.rl_episodes);
        (v, p)
    }))
}

/// The policy file of a run directory: its `checkpoints/latest.ckpt`, or the validation
/// snapshot its `train.select` chooses (`rule` overrides the run's own); `revalidated-return`
/// re-validates on every core with progress on stderr
/// ([`crate::revalidation::evaluate_snapshot`]), or reuses the run's `revalidation.jsonl`.
pub fn run_policy(run_dir: &Path, rule: Option<Select>) -> anyhow::Result<PathBuf> {
    run_policy_with(run_dir, rule, &mut crate::revalidation::evaluate_snapshot)
}

/// [`run_policy`], re-validating (`revalidated-return`) with `score`.
pub fn run_policy_with(
    run_dir: &Path,
    rule: Option<Select>,
    score: &mut Scorer<'_>,
) -> anyhow::Result<PathBuf> {
    let latest = run_dir.join("checkpoints").join("latest.ckpt");
    let config = RunFile::load(&run_dir.join("config.toml")).ok();
    let rule = rule
        .or_else(|| config.as_ref().map(|c| c.train.select))
        .unwrap_or_default();
    if rule == Select::Last {
        return Ok(latest);
    }
    let decay_end = config
        .as_ref()
        .map_or(0, |c| c.train.rl.epsilon_decay_episodes);
    let how = Plan::of(&config.map(|c| c.train).unwrap_or_default());
    match chosen_snapshot(run_dir, rule, decay_end, &how, score)? {
        Some((v, path)) => {
            eprintln!(
                "{}: train.select = \"{}\": the snapshot after {} RL episodes (validation success {:.2}, collision {:.2}, Disc. {})",
                run_dir.display(),
                rule.name(),
                v.rl_episodes,
                v.success,
                v.collision,
                v.disc.map_or("–".into(), |d| format!("{d:.3}"))
            );
            Ok(path)
        }
        None => bail!(
            "{}: train.select = \"{}\" but no validation snapshot in {} matches a validation line of metrics.jsonl",
            run_dir.display(),
            rule.name(),
            snapshot_dir(run_dir).display()
        ),
    }
}
