//! `train.select = "revalidated-return"` (issue 54): `best-return` without its winner's curse.
//! The best of ~20 validations of 100 episodes is partly luck: a run's snapshot after 2004 RL
//! episodes read 0.98 on its validation and tested 0.912, while later snapshots tested 0.98. So
//! the [`Plan::top`] snapshots by validation mean return after the ε decay, and the last
//! weights, are scored again on [`Plan::episodes`] fresh validation episodes (seeds
//! [`Plan::seed_start`].., never the validation seeds they were picked on, never the test
//! seeds), and the highest mean return there is the run's policy (ties: the later).
//!
//! Every candidate's result is a line of the run's `revalidation.jsonl`, appended and synced as
//! soon as it is scored, keyed by the snapshot's SHA-256 and the seeds: a re-run export or final
//! evaluation reuses the lines and scores only what is missing (an interrupted re-validation goes
//! on from the last finished candidate; a line cut short is skipped; a snapshot whose bytes
//! changed is scored again).

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use policy::method::TrainConfig;
use serde::{Deserialize, Serialize};

use crate::select::{best, snapshot_path, Validation};

/// The file of a run directory that records every re-validation.
pub const FILE: &str = "revalidation.jsonl";

/// One re-validation as a run's `[train]` resolves it (`train.revalidation`,
/// `policy::method::Revalidation`): how many candidates besides the last weights, how many
/// episodes each, from which seed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Plan {
    pub top: usize,
    pub episodes: u32,
    pub seed_start: u64,
}

impl Plan {
    pub fn of(train: &TrainConfig) -> Self {
        let r = &train.revalidation;
        Self {
            top: r.top,
            episodes: r.episodes_of(train.validation_episodes),
            seed_start: r.seed_start,
        }
    }

    /// The seeds of one candidate's re-validation.
    pub fn seeds(&self) -> std::ops::Range<u64> {
        self.seed_start..self.seed_start.saturating_add(self.episodes as u64)
    }
}

/// What one candidate scored on the re-validation seeds.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Scores {
    pub success_rate: f64,
    pub collision_rate: f64,
    pub timeout_rate: f64,
    pub discomfort: f64,
    /// Mean Nav. Time (s) of the successful episodes; `None` without a success.
    pub nav_time_s: Option<f64>,
    /// Mean return over the episodes: what the choice maximises.
    pub mean_return: f64,
}

/// One line of `revalidation.jsonl`: a candidate snapshot and its re-validation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Revalidated {
    /// The snapshot's file name (`ep-<N>.fsrlm` in `checkpoints/validation/`).
    pub snapshot: String,
    pub rl_episodes: u64,
    /// SHA-256 of the snapshot's bytes: a line is reused only for the same weights.
    pub sha256: String,
    pub seed_start: u64,
    pub episodes: u32,
    /// Whether the candidate is the run's last weights (its final validation's snapshot).
    pub last: bool,
    /// What its own validation (seeds `train.validation_seed_start..`) read.
    pub validation_mean_return: Option<f64>,
    #[serde(flatten)]
    pub scores: Scores,
    /// Wall-clock seconds of its re-validation.
    pub wall_s: f64,
    pub threads: usize,
}

/// The candidates of a re-validation among `on_disk` (validations whose snapshot loads): the
/// `top` validations with the highest mean return at or after `decay_end` RL episodes (ties:
/// the later), and the last weights (the latest validation: both training modes validate when
/// RL ends, so in a finished run it is the final network). In RL-episode order, each once.
/// Without a validation that has a return after the decay (a run shorter than its ε decay, as
/// short test runs are, or an old log) there is no plateau to choose within: the one candidate
/// is [`best`]'s, as `best-return` chooses then, and nothing is re-validated.
pub fn candidates(on_disk: &[Validation], decay_end: u64, top: usize) -> Vec<Validation> {
    let mut ranked: Vec<&Validation> = on_disk
        .iter()
        .filter(|v| v.rl_episodes >= decay_end && v.mean_return.is_some())
        .collect();
    // Highest return first; among equal returns the later first.
    ranked.sort_by(|a, b| {
        b.mean_return
            .partial_cmp(&a.mean_return)
            .unwrap_or(std::cmp::Ordering::Equal)
            .then(b.rl_episodes.cmp(&a.rl_episodes))
    });
    let mut out: Vec<Validation> = ranked.into_iter().take(top).cloned().collect();
    if out.is_empty() {
        return best(on_disk.iter().cloned()).into_iter().collect();
    }
    if let Some(last) = on_disk.iter().max_by_key(|v| v.rl_episodes) {
        out.push(last.clone());
    }
    out.sort_by_key(|v| v.rl_episodes);
    out.dedup_by_key(|v| v.rl_episodes);
    out
}

/// The re-validated candidate with the highest mean return (ties: the later).
pub fn best_revalidated(results: &[Revalidated]) -> Option<&Revalidated> {
    results.iter().fold(None, |acc, r| match acc {
        Some(b)
            if (r.scores.mean_return, r.rl_episodes) <= (b.scores.mean_return, b.rl_episodes) =>
        {
            Some(b)
        }
        _ => Some(r),
    })
}

/// The readable lines of a run's `revalidation.jsonl` (a line cut short or damaged is skipped;
/// no file: none).
pub fn read(run_dir: &Path) -> Vec<Revalidated> {
    std::fs::read_to_string(run_dir.join(FILE))
        .map(|text| {
            text.lines()
                .filter_map(|l| serde_json::from_str::<Revalidated>(l).ok())
                .filter(|r| r.scores.mean_return.is_finite())
                .collect()
        })
        .unwrap_or_default()
}

/// Appends `line` to the run's `revalidation.jsonl` and syncs it: a finished candidate survives
/// an interruption. A last line cut short by a crash is ended first, so that it spoils only
/// itself.
fn append(run_dir: &Path, line: &Revalidated) -> anyhow::Result<()> {
    let path = run_dir.join(FILE);
    let ends_clean = std::fs::read(&path).map_or(true, |b| b.is_empty() || b.ends_with(b"\n"));
    let mut text = if ends_clean {
        String::new()
    } else {
        "\n".into()
    };
    text += &serde_json::to_string(line)?;
    text.push('\n');
    let mut f = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&path)
        .with_context(|| format!("cannot open {}", path.display()))?;
    f.write_all(text.as_bytes())
        .and_then(|()| f.sync_data())
        .with_context(|| format!("cannot append to {}", path.display()))
}

/// Scores one snapshot on the re-validation seeds: `(path, how, k, n)`, the `k`-th (from 0) of
/// the `n` candidates this choice scores (the others' lines were in `revalidation.jsonl`).
pub type Scorer<'a> = dyn FnMut(&Path, &Plan, usize, usize) -> anyhow::Result<Scores> + 'a;

/// [`Select::RevalidatedReturn`](policy::method::Select::RevalidatedReturn)'s choice among the
/// validations of `run_dir` whose snapshot loads (`on_disk`): re-validates the [`candidates`]
/// (reusing the matching lines of `revalidation.jsonl`, appending the new ones), and returns
/// the one with the best re-validated return with its line. A single candidate is chosen
/// without re-validation (nothing to compare), and so is recorded by no line. `None` without a
/// candidate.
pub fn choose(
    run_dir: &Path,
    on_disk: &[Validation],
    decay_end: u64,
    how: &Plan,
    score: &mut Scorer<'_>,
) -> anyhow::Result<Option<(Validation, Option<Revalidated>)>> {
    if how.top == 0 || how.episodes == 0 {
        anyhow::bail!(
            "{}: train.revalidation needs top and episodes of at least 1, got {} and {}",
            run_dir.display(),
            how.top,
            how.episodes
        );
    }
    let cands = candidates(on_disk, decay_end, how.top);
    if cands.len() <= 1 {
        return Ok(cands.into_iter().next().map(|v| (v, None)));
    }
    let last_episode = on_disk.iter().map(|v| v.rl_episodes).max();
    let known = read(run_dir);
    // Each candidate's line from an earlier re-validation of the same weights on the same
    // seeds, or `None`: to be scored.
    let mut results: Vec<(PathBuf, String, Option<Revalidated>)> = Vec::new();
    for v in &cands {
        let path = snapshot_path(run_dir, v.rl_episodes);
        let sha256 = crate::policy_file::file_sha256(&path)?;
        let reuse = known.iter().rev().find(|r| {
            r.rl_episodes == v.rl_episodes
                && r.sha256 == sha256
                && r.seed_start == how.seed_start
                && r.episodes == how.episodes
        });
        results.push((path, sha256, reuse.cloned()));
    }
    let missing = results.iter().filter(|r| r.2.is_none()).count();
    let mut k = 0;
    for ((path, sha256, line), v) in results.iter_mut().zip(&cands) {
        if line.is_some() {
            continue;
        }
        let t0 = Instant::now();
        let scores = score(path, how, k, missing)
            .with_context(|| format!("re-validating {}", path.display()))?;
        k += 1;
        let new = Revalidated {
            snapshot: file_name(path),
            rl_episodes: v.rl_episodes,
            sha256: sha256.clone(),
            seed_start: how.seed_start,
            episodes: how.episodes,
            last: Some(v.rl_episodes) == last_episode,
            validation_mean_return: v.mean_return,
            scores,
            wall_s: t0.elapsed().as_secs_f64(),
            threads: threads(),
        };
        append(run_dir, &new)?;
        *line = Some(new);
    }
    let results: Vec<Revalidated> = results.into_iter().filter_map(|r| r.2).collect();
    let Some(top) = best_revalidated(&results).cloned() else {
        return Ok(None);
    };
    let chosen = cands
        .into_iter()
        .find(|v| v.rl_episodes == top.rl_episodes)
        .map(|v| (v, Some(top)));
    Ok(chosen)
}

fn file_name(p: &Path) -> String {
    p.file_name()
        .map_or_else(String::new, |n| n.to_string_lossy().into_owned())
}

/// The threads a re-validation runs on: every core.
pub fn threads() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// The scorer of `fsrl train`, `fsrl eval RUN` and `fsrl export-model RUN`: the snapshot's
/// greedy policy, in its own simulator and lookahead configuration, on the re-validation seeds
/// of its own setting, on every core (`crate::evaluation`'s evaluation), with progress on
/// stderr (a counter on a terminal, a line every 10 s otherwise) and a line per result.
pub fn evaluate_snapshot(path: &Path, how: &Plan, k: usize, n: usize) -> anyhow::Result<Scores> {
    use std::io::IsTerminal;
    use std::sync::atomic::{AtomicU32, Ordering};
    use std::sync::Mutex;
    let policy = crate::evaluation::LoadedPolicy::read(&crate::policy_file::Input {
        checkpoint: path.to_path_buf(),
        run_dir: None,
    })?;
    let name = file_name(path);
    let seeds = how.seeds();
    if k == 0 {
        eprintln!(
            "train.select = \"revalidated-return\": re-validating {n} candidate snapshot(s) on {} validation episodes each (seeds {}..{}, {} threads), into {FILE}",
            how.episodes,
            seeds.start,
            seeds.end - 1,
            threads()
        );
    }
    let plan = crate::evaluation::EvalPlan {
        settings: vec![policy.model.setting],
        seed_start: how.seed_start,
        episodes: how.episodes,
        threads: threads(),
        orca_safety_space_m: 0.0,
        planning_top_k: None,
        planning_breadth: None,
        crowd: Default::default(),
        shield_s: None,
        progress_tolerance: None,
    };
    let terminal = std::io::stderr().is_terminal();
    let done = AtomicU32::new(0);
    let t0 = Instant::now();
    let last_line = Mutex::new(Instant::now());
    let tick = || {
        let d = done.fetch_add(1, Ordering::Relaxed) + 1;
        if terminal {
            eprint!("\r  {name} ({}/{n}): {d}/{} episodes", k + 1, how.episodes);
        } else if let Ok(mut last) = last_line.lock() {
            if last.elapsed().as_secs() >= 10 {
                *last = Instant::now();
                eprintln!(
                    "  {name} ({}/{n}): {d}/{} episodes, {:.0} s",
                    k + 1,
                    how.episodes,
                    t0.elapsed().as_secs_f64()
                );
            }
        }
    };
    let report = policy.evaluate(&plan, &tick)?;
    let s = report
        .settings
        .first()
        .context("the re-validation scored no setting")?;
    let scores = Scores {
        success_rate: s.success,
        collision_rate: s.collision,
        timeout_rate: s.timeout,
        discomfort: s.disc,
        nav_time_s: s.nav_time_s,
        mean_return: s.mean_return,
    };
    if terminal {
        eprintln!();
    }
    eprintln!(
        "  {name} ({}/{n}): return {:.4}, success {:.3}, collision {:.3}, timeout {:.3}, Disc. {:.3}, Nav. Time {} ({:.0} s)",
        k + 1,
        scores.mean_return,
        scores.success_rate,
        scores.collision_rate,
        scores.timeout_rate,
        scores.discomfort,
        scores.nav_time_s.map_or("–".into(), |t| format!("{t:.2} s")),
        t0.elapsed().as_secs_f64()
    );
    Ok(scores)
}

/// The Markdown lines of a run's re-validation for its report ("How the run went"): every
/// candidate of the latest re-validation (the lines of `revalidation.jsonl` for the snapshot
/// `chosen` was chosen among, newest first per snapshot), its validation and re-validated
/// return, and which one is the policy; empty without `revalidation.jsonl`. Also the seconds the
/// re-validations took, for `run.json`.
pub fn summary(run_dir: &Path, chosen: Option<&Path>) -> (String, f64) {
    let lines = read(run_dir);
    let Some(newest) = lines.last() else {
        return (String::new(), 0.0);
    };
    // The latest line per snapshot re-validated as the newest line was, in RL-episode order.
    let mut latest: std::collections::BTreeMap<u64, &Revalidated> = Default::default();
    for r in lines
        .iter()
        .filter(|r| (r.seed_start, r.episodes) == (newest.seed_start, newest.episodes))
    {
        latest.insert(r.rl_episodes, r);
    }
    let chosen_name = chosen.map(file_name);
    let wall: f64 = latest.values().map(|r| r.wall_s).sum();
    let first = latest.values().next().map(|r| (r.seed_start, r.episodes));
    let (seed_start, episodes) = first.unwrap_or_default();
    let mut s = format!(
        "- re-validation (train.select = \"revalidated-return\"): {} candidates × {episodes} validation episodes (seeds {seed_start}..{}) in {wall:.0} s\n",
        latest.len(),
        (seed_start + episodes as u64).saturating_sub(1)
    );
    for r in latest.values() {
        let mark = if chosen_name.as_deref() == Some(r.snapshot.as_str()) {
            " ← the policy"
        } else {
            ""
        };
        s += &format!(
            "  - after {} RL episodes{}: validation return {}, re-validated return {:.4} (success {:.3}, collision {:.3}, timeout {:.3}, Disc. {:.3}){mark}\n",
            r.rl_episodes,
            if r.last { " (the last weights)" } else { "" },
            r.validation_mean_return
                .map_or("–".into(), |x| format!("{x:.4}")),
            r.scores.mean_return,
            r.scores.success_rate,
            r.scores.collision_rate,
            r.scores.timeout_rate,
            r.scores.discomfort,
        );
    }
    (s, wall)
}

/// The path of a run's re-validation file.
pub fn path(run_dir: &Path) -> PathBuf {
    run_dir.join(FILE)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::BTreeMap;

    use crate::policy_choice::run_policy_with;
    use crate::select::{snapshot_dir, tests::snapshot};
    use policy::method::Select;

    fn v(ep: u64, ret: f64) -> Validation {
        Validation {
            rl_episodes: ep,
            success: 0.95,
            collision: 0.05,
            disc: Some(0.05),
            nav_time_s: Some(12.0),
            mean_return: Some(ret),
        }
    }

    /// The default's: 4 candidates besides the last weights, 300 episodes from seed 10000.
    fn default_plan() -> Plan {
        let p = Plan::of(&TrainConfig::default());
        assert_eq!(
            p,
            Plan {
                top: 4,
                episodes: 300,
                seed_start: 10_000
            }
        );
        p
    }

    fn scores(ret: f64) -> Scores {
        Scores {
            success_rate: 0.9,
            collision_rate: 0.05,
            timeout_rate: 0.05,
            discomfort: 0.05,
            nav_time_s: Some(12.0),
            mean_return: ret,
        }
    }

    /// The top returns after the decay (ties: the later) and the last weights, each once.
    #[test]
    fn candidates_are_the_top_returns_after_the_decay_and_the_last_weights() {
        let all = [
            v(1000, 0.99), // before the decay: never a candidate
            v(2000, 0.98),
            v(2250, 0.90),
            v(2500, 0.95),
            v(2750, 0.95), // ties with 2500: the later ranks first
            v(3000, 0.97),
            v(3250, 0.80), // the last weights
        ];
        let eps = |c: Vec<Validation>| c.iter().map(|v| v.rl_episodes).collect::<Vec<_>>();
        assert_eq!(eps(candidates(&all, 2000, 3)), [2000, 2750, 3000, 3250]);
        assert_eq!(eps(candidates(&all, 2000, 1)), [2000, 3250]);
        assert_eq!(
            eps(candidates(&all, 2000, 4)),
            [2000, 2500, 2750, 3000, 3250]
        );
        // The last weights among the top: once.
        assert_eq!(eps(candidates(&all[..6], 2000, 2)), [2000, 3000]);
        // Old logs without returns, or a run shorter than its decay: the best success alone.
        let old: Vec<Validation> = all
            .iter()
            .map(|x| Validation {
                mean_return: None,
                success: if x.rl_episodes == 2250 { 1.0 } else { 0.9 },
                ..x.clone()
            })
            .collect();
        assert_eq!(eps(candidates(&old, 2000, 4)), [2250]);
        assert_eq!(eps(candidates(&all, 4000, 4)), [1000]);
        assert!(candidates(&[], 0, 4).is_empty());
    }

    /// The setting of the issue: the best 100-episode validation (0.98 after 2000 episodes) is
    /// luck, the re-validated best (3000) is chosen; ties go to the later; the line of every
    /// candidate is in `revalidation.jsonl`, and a second choice reuses them.
    #[test]
    fn the_revalidated_best_beats_a_lucky_validation() {
        let dir = tempfile::tempdir().unwrap();
        let run = dir.path();
        std::fs::create_dir_all(snapshot_dir(run)).unwrap();
        let all = [v(2000, 0.98), v(2500, 0.93), v(3000, 0.95), v(3500, 0.90)];
        for x in &all {
            snapshot(&snapshot_path(run, x.rl_episodes));
        }
        // What 300 fresh episodes say of each.
        let truth = BTreeMap::from([(2000, 0.85), (2500, 0.90), (3000, 0.93), (3500, 0.93)]);
        let calls = std::cell::RefCell::new(Vec::new());
        let mut score = |p: &Path, how: &Plan, _k: usize, n: usize| {
            assert_eq!((how.episodes, n), (300, 3));
            let ep = all
                .iter()
                .find(|x| snapshot_path(run, x.rl_episodes) == p)
                .unwrap()
                .rl_episodes;
            calls.borrow_mut().push(ep);
            Ok(scores(truth[&ep]))
        };
        let how = Plan {
            top: 2,
            ..default_plan()
        };
        // Candidates 2000 and 3000 (top 2) and 3500 (the last weights); 3000 and 3500 tie at
        // 0.93: the later.
        let (chosen, line) = choose(run, &all, 2000, &how, &mut score).unwrap().unwrap();
        assert_eq!(chosen.rl_episodes, 3500);
        let line = line.unwrap();
        assert!(line.last && line.scores.mean_return == 0.93, "{line:?}");
        assert_eq!(*calls.borrow(), [2000, 3000, 3500]);
        let lines = read(run);
        assert_eq!(lines.len(), 3);
        assert_eq!(lines[0].validation_mean_return, Some(0.98));
        assert_eq!(lines[0].scores.mean_return, 0.85);
        assert_eq!((lines[0].seed_start, lines[0].episodes), (10_000, 300));
        // Without the tie, the re-validated best that was not the last.
        let truth2 = BTreeMap::from([(2000, 0.85), (3000, 0.95), (3500, 0.90)]);
        let fresh = tempfile::tempdir().unwrap();
        let mut other = |p: &Path, _: &Plan, _: usize, _: usize| {
            let ep = all
                .iter()
                .find(|x| snapshot_path(fresh.path(), x.rl_episodes) == p)
                .unwrap()
                .rl_episodes;
            Ok(scores(truth2[&ep]))
        };
        std::fs::create_dir_all(snapshot_dir(fresh.path())).unwrap();
        for x in &all {
            snapshot(&snapshot_path(fresh.path(), x.rl_episodes));
        }
        let (chosen, _) = choose(fresh.path(), &all, 2000, &how, &mut other)
            .unwrap()
            .unwrap();
        assert_eq!(chosen.rl_episodes, 3000);
        // Again on the first run: nothing scored again, the same choice.
        let mut never = |_: &Path, _: &Plan, _: usize, _: usize| -> anyhow::Result<Scores> {
            panic!("re-validated again although revalidation.jsonl has every candidate")
        };
        let (again, _) = choose(run, &all, 2000, &how, &mut never).unwrap().unwrap();
        assert_eq!(again.rl_episodes, 3500);
        assert_eq!(read(run).len(), 3);
        // Other seeds or episodes are another re-validation: scored again.
        let more = Plan {
            episodes: 500,
            ..how
        };
        calls.borrow_mut().clear();
        choose(run, &all, 2000, &more, &mut |p, _, k, _| {
            score(p, &how, k, 3)
        })
        .unwrap();
        assert_eq!(*calls.borrow(), [2000, 3000, 3500]);
    }

    /// An interrupted re-validation (the file ends in a line cut short) goes on from the last
    /// finished candidate; a snapshot whose bytes changed is scored again.
    #[test]
    fn an_interrupted_revalidation_goes_on_and_changed_weights_are_scored_again() {
        let dir = tempfile::tempdir().unwrap();
        let run = dir.path();
        std::fs::create_dir_all(snapshot_dir(run)).unwrap();
        let all = [v(2000, 0.98), v(3000, 0.95), v(4000, 0.90)];
        for x in &all {
            snapshot(&snapshot_path(run, x.rl_episodes));
        }
        let how = default_plan();
        let scored = std::cell::RefCell::new(Vec::new());
        let mut score = |p: &Path, _: &Plan, _: usize, _: usize| {
            let ep = all
                .iter()
                .find(|x| snapshot_path(run, x.rl_episodes) == p)
                .unwrap()
                .rl_episodes;
            scored.borrow_mut().push(ep);
            Ok(scores(ep as f64 / 10_000.0))
        };
        choose(run, &all, 0, &how, &mut score).unwrap();
        assert_eq!(*scored.borrow(), [2000, 3000, 4000]);
        // Interrupted while writing the last line: keep the first one and half of the second.
        let text = std::fs::read_to_string(path(run)).unwrap();
        let mut cut: Vec<&str> = text.lines().collect();
        let half = &cut[1][..cut[1].len() / 2];
        cut.truncate(1);
        std::fs::write(path(run), format!("{}\n{half}", cut[0])).unwrap();
        scored.borrow_mut().clear();
        let (chosen, _) = choose(run, &all, 0, &how, &mut score).unwrap().unwrap();
        assert_eq!(chosen.rl_episodes, 4000);
        assert_eq!(*scored.borrow(), [3000, 4000]);
        // The cut line spoils only itself: three readable lines now.
        assert_eq!(read(run).len(), 3);
        // New weights under an old name (a resumed run's final validation): scored again.
        let mut other = std::fs::read(snapshot_path(run, 4000)).unwrap();
        other.push(0);
        std::fs::write(snapshot_path(run, 4000), other).unwrap();
        scored.borrow_mut().clear();
        choose(run, &all, 0, &how, &mut score).unwrap();
        assert_eq!(*scored.borrow(), [4000]);
    }

    /// Through the run directory, as `fsrl eval RUN` and the final evaluation choose: a missing
    /// or damaged snapshot is never a candidate (the last weights are the last one that loads),
    /// the run's `[train.revalidation]` is used, and a single candidate is chosen unscored.
    #[test]
    fn a_run_directory_re_validates_only_snapshots_that_load() {
        let dir = tempfile::tempdir().unwrap();
        let run = dir.path();
        std::fs::create_dir_all(snapshot_dir(run)).unwrap();
        let line = |ep: u64, r: f64| {
            format!(
                "{{\"phase\":\"validation\",\"episode\":{ep},\"success_rate\":0.95,\"collision_rate\":0.05,\"mean_return\":{r}}}\n"
            )
        };
        std::fs::write(
            run.join("metrics.jsonl"),
            [
                line(100, 0.99),
                line(200, 0.98),
                line(300, 0.97),
                line(400, 0.90),
                line(500, 0.80),
            ]
            .concat(),
        )
        .unwrap();
        std::fs::write(
            run.join("config.toml"),
            "[train]\nselect = \"revalidated-return\"\n[train.rl]\nepsilon_decay_episodes = 200\n\
             [train.revalidation]\ntop = 2\nepisodes = 7\nseed_start = 5000\n",
        )
        .unwrap();
        // 200 damaged, 500 (the newest validation) never written: 300 and 400 (the last
        // weights that load) are the candidates.
        for ep in [100, 300, 400] {
            snapshot(&snapshot_path(run, ep));
        }
        std::fs::write(snapshot_path(run, 200), b"damaged").unwrap();
        let seen = std::cell::RefCell::new(Vec::new());
        let mut score = |p: &Path, how: &Plan, _: usize, _: usize| {
            assert_eq!((how.top, how.episodes, how.seed_start), (2, 7, 5000));
            seen.borrow_mut().push(p.to_path_buf());
            // The last weights re-validate better.
            Ok(scores(if p == snapshot_path(run, 400) {
                0.95
            } else {
                0.9
            }))
        };
        let chosen = run_policy_with(run, None, &mut score).unwrap();
        assert_eq!(chosen, snapshot_path(run, 400));
        assert_eq!(
            *seen.borrow(),
            [snapshot_path(run, 300), snapshot_path(run, 400)]
        );
        let (md, _) = summary(run, Some(&chosen));
        assert!(
            md.contains("2 candidates × 7 validation episodes (seeds 5000..5006)"),
            "{md}"
        );
        assert!(
            md.contains("after 400 RL episodes (the last weights): validation return 0.9000, re-validated return 0.9500")
                && md.contains("← the policy"),
            "{md}"
        );
        // Another rule on the same run re-validates nothing.
        let mut never = |_: &Path, _: &Plan, _: usize, _: usize| -> anyhow::Result<Scores> {
            panic!("best-return re-validated")
        };
        assert_eq!(
            run_policy_with(run, Some(Select::BestReturn), &mut never).unwrap(),
            snapshot_path(run, 300)
        );
        // One candidate (the best after the decay is the last weights): chosen unscored.
        std::fs::remove_file(snapshot_path(run, 400)).unwrap();
        assert_eq!(
            run_policy_with(run, None, &mut never).unwrap(),
            snapshot_path(run, 300)
        );
    }
}
