//! The numbers behind the pictures of `fsrl plot`: outcome bars per setting and method (the
//! paper's Fig. 5) with their intervals, the reward ablation (Fig. 8–9: each arm averaged per
//! seed over Env 1–3, Welch's test against R_c), and the learning-curve runs of run directories.
//! `viz` draws them.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::bail;
use sim::Setting;
use viz::{Interval, OutcomeCell};

use crate::compare::Group;
use crate::report::{Metric, SubjectReport};

fn clip(x: f64) -> f64 {
    x.clamp(0.0, 1.0)
}

/// A rate's bar: a single run's Wilson interval, or mean ± std over runs.
fn rate_interval(g: &Group, metric: Metric, setting: Setting) -> Option<Interval> {
    if let Some(r) = g.single(setting) {
        let (v, ci) = metric.of(r)?;
        let [lo, hi] = ci.unwrap_or([v, v]);
        return Some(Interval { mean: v, lo, hi });
    }
    let st = g.stat(metric, setting)?;
    let sd = st.std.unwrap_or(0.0);
    Some(Interval {
        mean: st.mean,
        lo: clip(st.mean - sd),
        hi: clip(st.mean + sd),
    })
}

fn outcome_cell(g: &Group, setting: Setting) -> Option<OutcomeCell> {
    Some(OutcomeCell {
        success: rate_interval(g, Metric::Success, setting)?,
        collision: rate_interval(g, Metric::Collision, setting)?,
        timeout: rate_interval(g, Metric::Timeout, setting)?,
    })
}

const INTERVAL_NOTE: &str =
    "error bars: 95% Wilson interval for a single run, ± standard deviation over runs otherwise";

pub fn pretty_setting(s: Setting) -> String {
    let name = s.name();
    let (env, vis) = name.split_once('-').unwrap_or((name, ""));
    format!("Env {} ({vis})", env.trim_start_matches("env"))
}

/// A method's runs per setting: `3`, or `1–3` where the settings have different numbers of runs
/// (a grid whose seeds are not all trained yet).
fn runs_label(g: &Group) -> String {
    let (lo, hi) = (g.runs_by_setting().min(), g.runs_per_setting());
    match lo {
        Some(lo) if lo != hi => format!("{lo}–{hi}"),
        _ => hi.to_string(),
    }
}

/// Outcome rates per setting (those with a result) and method; `title` or a default.
pub fn outcome_bars(groups: &[Group], title: Option<String>) -> Option<viz::OutcomeBars> {
    let settings: Vec<Setting> = Setting::ALL
        .iter()
        .copied()
        .filter(|&s| {
            groups
                .iter()
                .any(|g| g.single(s).is_some() || g.stat(Metric::Success, s).is_some())
        })
        .collect();
    if settings.is_empty() {
        return None;
    }
    Some(viz::OutcomeBars {
        title: title.unwrap_or_else(|| "Outcome rates per setting and method".into()),
        settings: settings.iter().map(|&s| pretty_setting(s)).collect(),
        methods: groups
            .iter()
            .map(|g| format!("{} ({})", g.method, runs_label(g)))
            .collect(),
        cells: settings
            .iter()
            .map(|&s| groups.iter().map(|g| outcome_cell(g, s)).collect())
            .collect(),
        interval_note: format!("{INTERVAL_NOTE}; (n) = runs per setting"),
    })
}

/// A run's training log for the learning curves: `path` is a run directory (its
/// `metrics.jsonl`) or a metrics file; the label is the run directory's name. A last line cut
/// short is left out with a warning on stderr.
pub fn curve_run(path: &Path) -> anyhow::Result<viz::CurveRun> {
    let file = if path.is_dir() {
        path.join("metrics.jsonl")
    } else {
        path.to_path_buf()
    };
    let metrics = viz::metrics::read_metrics(&file)?;
    if metrics.torn_last_line {
        eprintln!(
            "warning: {}: the last line is cut short (the run stopped while writing it); left out",
            file.display()
        );
    }
    let dir = if path.is_dir() {
        path.to_path_buf()
    } else {
        path.parent().map(PathBuf::from).unwrap_or_default()
    };
    let label = dir
        .canonicalize()
        .ok()
        .and_then(|p| p.file_name().map(|n| n.to_string_lossy().into_owned()))
        .unwrap_or_else(|| path.display().to_string());
    Ok(viz::CurveRun { label, metrics })
}

/// The reward ablation over the invisible or the visible Env 1–3: the figure and its numbers as
/// Markdown (per arm mean ± std over seed averages, Welch's test against R_c, the per-seed
/// values). An error when no arm has a result.
pub fn ablation(
    groups: &[Group],
    visible: bool,
    title: Option<String>,
) -> anyhow::Result<(viz::Ablation, String)> {
    let visibility = if visible { "visible" } else { "invisible" };
    let envs: Vec<Setting> = Setting::ALL
        .iter()
        .copied()
        .filter(|s| s.robot_visible == visible)
        .collect();
    let variants = [
        ("sarl", "R_c (sarl)"),
        ("sarl+foresight", "+R_f"),
        ("sarl+efficiency", "+R_t"),
        ("fsrl", "all (fsrl)"),
    ];
    let interval = |g: Option<&Group>, metric: Metric, rate: bool| -> Option<Interval> {
        let (mean, std) = crate::report::mean_std(&seed_averages(&g?.members, &envs, metric))?;
        let sd = std.unwrap_or(0.0);
        let (lo, hi) = (mean - sd, mean + sd);
        Some(if rate {
            Interval {
                mean,
                lo: clip(lo),
                hi: clip(hi),
            }
        } else {
            Interval {
                mean,
                lo: lo.max(0.0),
                hi,
            }
        })
    };
    let find = |m: &str| groups.iter().find(|g| g.method == m);
    if variants.iter().all(|(m, _)| find(m).is_none()) {
        bail!("none of sarl, sarl+foresight, sarl+efficiency, fsrl among the sources");
    }
    let fig = viz::Ablation {
        title: title
            .unwrap_or_else(|| format!("Reward ablation: averages over Env 1–3 ({visibility})")),
        variants: variants
            .iter()
            .map(|(m, label)| {
                let seeds = find(m).map_or(0, |g| {
                    seed_averages(&g.members, &envs, Metric::Success).len()
                });
                format!("{label} ({seeds})")
            })
            .collect(),
        outcomes: variants
            .iter()
            .map(|(m, _)| {
                let g = find(m);
                Some(OutcomeCell {
                    success: interval(g, Metric::Success, true)?,
                    collision: interval(g, Metric::Collision, true)?,
                    timeout: interval(g, Metric::Timeout, true)?,
                })
            })
            .collect(),
        nav_time_s: variants
            .iter()
            .map(|(m, _)| interval(find(m), Metric::NavTime, false))
            .collect(),
        disc: variants
            .iter()
            .map(|(m, _)| interval(find(m), Metric::Disc, false))
            .collect(),
        interval_note:
            "error bars: ± standard deviation over seeds (none for one); (n) = seeds with all three envs"
                .into(),
    };
    let members = |m: &str| find(m).map_or(&[][..], |g| g.members.as_slice());
    let table = ablation_markdown(&variants, members, &envs, visibility);
    Ok((fig, table))
}

/// The ablation's numbers: per arm, mean ± std over its seeds' averages over `envs`, and Welch's
/// test of each arm against the first (R_c) over those seed averages.
pub fn ablation_markdown<'a>(
    variants: &[(&str, &str)],
    members: impl Fn(&str) -> &'a [SubjectReport],
    envs: &[Setting],
    visibility: &str,
) -> String {
    const METRICS: [Metric; 5] = [
        Metric::Success,
        Metric::Collision,
        Metric::Timeout,
        Metric::NavTime,
        Metric::Disc,
    ];
    let mut s = format!(
        "Reward ablation, {visibility}: each arm's value is the mean ± std over its training seeds of the seed's average over Env 1–3 (seeds with a result in all three; per seed in seed order in brackets below the table); p: Welch's test against R_c over the seed averages.\n\n| arm | seeds | Succ. | Coll. | Timeout | Nav. Time (s) | Disc. |\n|---|---|---|---|---|---|---|\n"
    );
    let base: Vec<Vec<f64>> = METRICS
        .iter()
        .map(|&m| seed_averages(members(variants[0].0), envs, m))
        .collect();
    let mut per_seed = String::new();
    for (i, (method, label)) in variants.iter().enumerate() {
        let values: Vec<Vec<f64>> = METRICS
            .iter()
            .map(|&m| seed_averages(members(method), envs, m))
            .collect();
        let cells: Vec<String> = METRICS
            .iter()
            .zip(&values)
            .zip(&base)
            .map(|((metric, xs), b)| {
                let mut c = crate::report::mean_std_cell(xs, metric.digits());
                if i > 0 {
                    if let Some(w) = crate::report::welch(xs, b) {
                        let _ = write!(c, " (p = {:.2})", w.p);
                    }
                }
                c
            })
            .collect();
        let _ = writeln!(
            s,
            "| {label} | {} | {} |",
            values[0].len(),
            cells.join(" | ")
        );
        let fmt = |k: usize| {
            values[k]
                .iter()
                .map(|v| format!("{v:.prec$}", prec = METRICS[k].digits()))
                .collect::<Vec<_>>()
                .join(", ")
        };
        let _ = writeln!(
            per_seed,
            "- {label}: Succ. [{}], Nav. Time [{}], Disc. [{}]",
            fmt(0),
            fmt(3),
            fmt(4)
        );
    }
    s.push('\n');
    s.push_str(&per_seed);
    s
}

/// A method's `metric` averaged over `envs`, one value per training seed, as the paper's ablation
/// averages each arm over the three environments. The members of one seed are taken together: a
/// grid of `fsrl reproduce` has one member per setting (each trained there), an evaluation of one
/// model on all six settings a single member with every setting; a seed counts only with a result
/// in each of `envs` (an average over fewer would not be the same quantity). Members that do not
/// know their seed count each on their own.
pub fn seed_averages(members: &[SubjectReport], envs: &[Setting], metric: Metric) -> Vec<f64> {
    let mut by_seed: BTreeMap<(Option<u64>, usize), Vec<Vec<f64>>> = BTreeMap::new();
    for (i, m) in members.iter().enumerate() {
        let key = m.run_seed.map_or((None, i), |s| (Some(s), 0));
        let per_env = by_seed
            .entry(key)
            .or_insert_with(|| vec![Vec::new(); envs.len()]);
        for (vals, &s) in per_env.iter_mut().zip(envs) {
            if let Some((v, _)) = m.setting(s).and_then(|r| metric.of(r)) {
                vals.push(v);
            }
        }
    }
    by_seed
        .values()
        .filter_map(|per_env| {
            let means = per_env
                .iter()
                .map(|v| crate::report::mean_std(v).map(|m| m.0))
                .collect::<Option<Vec<f64>>>()?;
            crate::report::mean_std(&means).map(|m| m.0)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::report::SettingReport;

    fn result(setting: Setting, success: f64) -> SettingReport {
        SettingReport {
            setting: setting.name().to_string(),
            episodes: 100,
            successes: (success * 100.0) as u32,
            collisions: 0,
            timeouts: 0,
            success,
            success_ci95: None,
            collision: 0.0,
            collision_ci95: None,
            timeout: 0.0,
            timeout_ci95: None,
            nav_time_s: Some(10.0),
            nav_time_ci95_s: None,
            nav_time_std_s: None,
            disc: 0.0,
            danger_steps: 0,
            steps: 0,
            path_length_m: None,
            path_length_std_m: None,
            mean_abs_rotation_rad: 0.0,
            mean_return: 0.0,
            return_std: None,
            walls: None,
        }
    }

    fn member(seed: Option<u64>, results: &[(usize, f64)]) -> SubjectReport {
        SubjectReport {
            label: String::new(),
            method: "sarl".into(),
            checkpoint: None,
            checkpoint_sha256: None,
            policy_version: 0,
            run_seed: seed,
            planning_top_k: 0,
            planning_breadth: 0,
            shield_s: 0.0,
            progress_tolerance: 0.0,
            trained_setting: None,
            settings: results
                .iter()
                .map(|&(i, v)| result(Setting::ALL[i], v))
                .collect(),
        }
    }

    #[test]
    fn the_ablation_averages_each_seed_over_the_three_environments() {
        let envs = [Setting::ALL[0], Setting::ALL[1], Setting::ALL[2]];
        assert!(envs.iter().all(|s| !s.robot_visible));
        let members = [
            // Seed 0 as a grid: one run per environment.
            member(Some(0), &[(0, 0.9)]),
            member(Some(0), &[(1, 0.6)]),
            member(Some(0), &[(2, 0.3)]),
            // Seed 1 trained in Env 1 only: not an average over the three, left out.
            member(Some(1), &[(0, 1.0)]),
            // A model evaluated everywhere, seed unknown: its own average (visible ignored).
            member(None, &[(0, 0.5), (1, 0.5), (2, 0.8), (3, 0.0)]),
        ];
        let v = seed_averages(&members, &envs, Metric::Success);
        assert_eq!(v.len(), 2, "{v:?}");
        assert!(
            (v[0] - 0.6).abs() < 1e-12 && (v[1] - 0.6).abs() < 1e-12,
            "{v:?}"
        );
        // Two runs of one seed in the same environment count as their mean there.
        let twice = [
            member(Some(3), &[(0, 0.2), (1, 0.2), (2, 0.2)]),
            member(Some(3), &[(2, 0.8)]),
        ];
        let v = seed_averages(&twice, &envs, Metric::Success);
        assert_eq!(v.len(), 1);
        assert!((v[0] - 0.3).abs() < 1e-12, "{v:?}");
        assert!(seed_averages(&[], &envs, Metric::Success).is_empty());
    }

    #[test]
    fn the_ablation_table_tests_each_arm_against_r_c_over_seed_averages() {
        let envs = [Setting::ALL[0], Setting::ALL[1], Setting::ALL[2]];
        let grid = |seed: u64, s: [f64; 3]| -> Vec<SubjectReport> {
            (0..3).map(|i| member(Some(seed), &[(i, s[i])])).collect()
        };
        // R_c: seed averages 0.6 and 0.7; +R_f: 0.9 and 0.95; +R_t and fsrl: nothing.
        let rc: Vec<SubjectReport> = [grid(0, [0.9, 0.6, 0.3]), grid(1, [0.7, 0.7, 0.7])].concat();
        let rf: Vec<SubjectReport> = [grid(0, [0.9, 0.9, 0.9]), grid(1, [1.0, 0.9, 0.95])].concat();
        let variants = [
            ("sarl", "R_c"),
            ("sarl+foresight", "+R_f"),
            ("sarl+efficiency", "+R_t"),
        ];
        let md = ablation_markdown(
            &variants,
            |m| match m {
                "sarl" => rc.as_slice(),
                "sarl+foresight" => rf.as_slice(),
                _ => &[],
            },
            &envs,
            "invisible",
        );
        assert!(
            md.contains("| R_c | 2 | 0.650 ± 0.071 | 0.000 ± 0.000 |"),
            "{md}"
        );
        let w = crate::report::welch(&[0.9, 0.95], &[0.6, 0.7]).unwrap();
        assert!(
            md.contains(&format!("| +R_f | 2 | 0.925 ± 0.035 (p = {:.2}) |", w.p)),
            "{md}"
        );
        assert!(md.contains("| +R_t | 0 | – | – | – | – | – |"), "{md}");
        assert!(
            md.contains("- +R_f: Succ. [0.900, 0.950], Nav. Time [10.00, 10.00]"),
            "{md}"
        );
    }
}
