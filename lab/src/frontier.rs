//! `fsrl plot frontier`: the policies runs passed through, each validated snapshot as a point of
//! (Nav. Time, Disc.), beside the paper's row of its method and setting. Answers whether another
//! snapshot of the same runs could have shipped the paper's point: as fast *and* as gentle
//! (`docs/REPRODUCTION.md`, Experiment 13), and how the methods compare at a common speed and
//! over their whole trajectories, no snapshot chosen (Experiment 14), and which snapshot of each
//! run is the gentlest at a speed common to all methods (`--pick common-speed`, Experiment 15). Only the snapshots `low-disc` may choose from take
//! part: after the ε decay, validation success at least
//! [`policy::method::LOW_DISC_MIN_SUCCESS`] (`--min-success` changes it). Validation
//! seeds only; 100 episodes a validation, so a point is uncertain by about ±0.5 s and ±0.02 Disc.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use policy::method::Select;
use sim::Setting;

use crate::report::{mean_std_cell, welch, Metric};
use crate::run::RunFile;
use crate::select::{self, Validation};

/// One run's validated snapshots.
#[derive(Debug, Clone, PartialEq)]
pub struct RunSnapshots {
    pub run: PathBuf,
    pub method: String,
    pub setting: Setting,
    pub seed: u64,
    /// The snapshots `low-disc` may choose from that have Nav. Time and Disc.
    pub good: Vec<Validation>,
    /// The snapshot the run's `train.select` ships (`None` for `last`).
    pub chosen: Option<Validation>,
}

impl RunSnapshots {
    /// The paper's `(Nav. Time, Disc.)` for this method and setting.
    pub fn paper(&self) -> Option<(f64, f64)> {
        Some((
            Metric::NavTime.paper(&self.method, self.setting)?,
            Metric::Disc.paper(&self.method, self.setting)?,
        ))
    }

    /// The good snapshots at least as fast and as gentle as the paper's row.
    pub fn reaching_paper(&self) -> Vec<&Validation> {
        let Some((nav, disc)) = self.paper() else {
            return Vec::new();
        };
        self.good
            .iter()
            .filter(|v| point(v).is_some_and(|p| p.0 <= nav && p.1 <= disc))
            .collect()
    }
}

/// `(Nav. Time, Disc.)` of a validation, where it has both.
pub fn point(v: &Validation) -> Option<(f64, f64)> {
    Some((v.nav_time_s?, v.disc?))
}

/// What to assume of a run directory without its `config.toml` (e.g. the metrics logs committed
/// in `docs/results/paper-schedule/`): all three must be given for such a directory.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Assumed {
    pub method: Option<String>,
    pub setting: Option<String>,
    /// The end of the run's ε decay (RL episodes): snapshots before it do not count.
    pub decay_end: Option<u64>,
}

/// Reads a run directory: its `config.toml` (method, setting, seed, ε decay, select rule), or
/// without one what `assumed` says, and its `metrics.jsonl` validations.
pub fn read_run(run: &Path, assumed: &Assumed, min_success: f64) -> anyhow::Result<RunSnapshots> {
    let config_path = run.join("config.toml");
    let metrics = run.join("metrics.jsonl");
    let (method, setting, seed, decay_end, rule) = if config_path.is_file() {
        let c = RunFile::load(&config_path)?;
        let decay = c.train.rl.epsilon_decay_episodes;
        (
            c.run.method,
            c.run.setting,
            c.run.seed,
            decay,
            c.train.select,
        )
    } else if !metrics.is_file() {
        bail!(
            "{}: not a run directory (no config.toml or metrics.jsonl; `fsrl plot frontier` takes the run directories of `fsrl train` or `fsrl reproduce`)",
            run.display()
        );
    } else {
        let (Some(method), Some(setting), Some(decay)) =
            (&assumed.method, &assumed.setting, assumed.decay_end)
        else {
            bail!(
                "{}: no config.toml beside metrics.jsonl: pass --method, --setting and --decay-end for it",
                run.display()
            );
        };
        // The seed from a trailing `-s<seed>` of the directory's name, if it has one.
        let seed = run
            .file_name()
            .and_then(|n| n.to_str()?.rsplit_once("-s")?.1.parse().ok())
            .unwrap_or(0);
        (method.clone(), setting.clone(), seed, decay, Select::Last)
    };
    let setting: Setting = setting
        .parse()
        .with_context(|| format!("{}: the run's setting", run.display()))?;
    let text = std::fs::read_to_string(&metrics)
        .with_context(|| format!("cannot read {}", metrics.display()))?;
    let (all, skipped) = select::validations(&text);
    if skipped > 0 {
        eprintln!(
            "warning: {}: {skipped} unreadable or impossible line(s) skipped",
            metrics.display()
        );
    }
    // The rule's choice among all the validations, as when the run ended (every snapshot on
    // disk): so a log kept without its snapshots (docs/results/frontier/logs/) still shows it.
    let chosen = select::choose(rule, all.iter().cloned(), decay_end);
    Ok(RunSnapshots {
        run: run.to_path_buf(),
        method,
        setting,
        seed,
        good: all
            .into_iter()
            .filter(|v| select::good_after(v, decay_end, min_success) && point(v).is_some())
            .collect(),
        chosen,
    })
}

/// The figure: one panel per setting (in [`Setting::ALL`] order), one group per method.
pub fn figure(runs: &[RunSnapshots], title: Option<String>, min_success: f64) -> viz::Frontier {
    let mut by_setting: BTreeMap<usize, BTreeMap<&str, Vec<&RunSnapshots>>> = BTreeMap::new();
    for r in runs {
        by_setting
            .entry(r.setting.index())
            .or_default()
            .entry(r.method.as_str())
            .or_default()
            .push(r);
    }
    let panels = by_setting
        .into_iter()
        .map(|(i, methods)| viz::FrontierPanel {
            caption: Setting::ALL[i].name().to_string(),
            groups: methods
                .into_iter()
                .map(|(method, rs)| viz::FrontierGroup {
                    label: method.to_string(),
                    points: rs
                        .iter()
                        .flat_map(|r| r.good.iter().filter_map(point))
                        .collect(),
                    chosen: rs
                        .iter()
                        .filter_map(|r| r.chosen.as_ref().and_then(point))
                        .collect(),
                    paper: rs[0].paper(),
                })
                .collect(),
        })
        .collect();
    viz::Frontier {
        title: title.unwrap_or_else(|| "Validated snapshots: Nav. Time against Disc.".into()),
        note: format!(
            "snapshots after the ε decay with success ≥ {min_success} in their validation line; below and left of × is as fast and as gentle as the paper"
        ),
        panels,
    }
}

fn cell(v: Option<&Validation>) -> String {
    match v.and_then(|v| point(v).map(|p| (v.rl_episodes, p))) {
        Some((ep, (nav, disc))) => format!("{nav:.2} s / {disc:.3} (ep {ep})"),
        None => "–".into(),
    }
}

/// The table: per run the good snapshots, the fastest, the gentlest, the shipped one, the
/// paper's point and how many snapshots reach it; a total line at the end.
pub fn markdown(runs: &[RunSnapshots], min_success: f64) -> String {
    let mut s = format!(
        "Validated snapshots (after the ε decay, success ≥ {min_success} in their validation line): Nav. Time (s) / Disc. as the line records them. \"Reach\": snapshots at least as fast and as gentle as the paper's row.\n\n| run | method | setting | seed | snapshots | fastest | gentlest | shipped | paper | reach |\n|---|---|---|---|---|---|---|---|---|---|\n"
    );
    let (mut total, mut reach) = (0, 0);
    for r in runs {
        let by = |key: fn(&(f64, f64)) -> f64| {
            r.good
                .iter()
                .filter_map(|v| point(v).map(|p| (key(&p), v)))
                .min_by(|a, b| a.0.total_cmp(&b.0))
                .map(|(_, v)| v)
        };
        let n_reach = r.reaching_paper().len();
        total += r.good.len();
        reach += n_reach;
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
            r.run.file_name().map_or_else(
                || r.run.display().to_string(),
                |n| n.to_string_lossy().into_owned()
            ),
            r.method,
            r.setting.name(),
            r.seed,
            r.good.len(),
            cell(by(|p| p.0)),
            cell(by(|p| p.1)),
            cell(r.chosen.as_ref()),
            r.paper()
                .map_or("–".into(), |(n, d)| format!("{n:.2} s / {d:.2}")),
            if r.paper().is_some() {
                n_reach.to_string()
            } else {
                "–".into()
            },
        );
    }
    let _ = writeln!(
        s,
        "\n{reach} of {total} snapshots in {} runs reach the paper's point of their method and setting.",
        runs.len()
    );
    let common = at_common_speed(runs);
    if !common.is_empty() {
        s.push_str(
            "\n## Disc. at a common Nav. Time\n\nEach run's Disc. at its setting's common Nav. Time (the median over every method's snapshots there), from the least-squares line of Disc. on Nav. Time through its snapshots (runs with at least 3): the methods compared at the same speed instead of at the points their runs shipped. Mean ± std over runs; Welch's test where a setting has two methods with two runs or more each.\n\n| setting | at Nav. Time (s) | method | runs | Disc. | slope (Disc. per s) |\n|---|---|---|---|---|---|\n",
        );
        let mut tests = String::new();
        for c in &common {
            for (method, fits) in &c.methods {
                let at: Vec<f64> = fits.iter().map(|f| f.at(c.nav_time)).collect();
                let slopes: Vec<f64> = fits.iter().map(|f| f.slope).collect();
                let _ = writeln!(
                    s,
                    "| {} | {:.2} | {method} | {} | {} | {} |",
                    c.setting.name(),
                    c.nav_time,
                    fits.len(),
                    mean_std_cell(&at, 3),
                    mean_std_cell(&slopes, 3)
                );
            }
            if let [(a, fa), (b, fb)] = c.methods.as_slice() {
                let at =
                    |fits: &[LineFit]| fits.iter().map(|f| f.at(c.nav_time)).collect::<Vec<_>>();
                if let Some(w) = welch(&at(fa), &at(fb)) {
                    let _ = writeln!(
                        tests,
                        "- {}: {a} − {b} = {:+.3} at {:.2} s (Welch p = {:.2})",
                        c.setting.name(),
                        w.difference,
                        c.nav_time,
                        w.p
                    );
                }
            }
        }
        if !tests.is_empty() {
            s.push('\n');
            s.push_str(&tests);
        }
    }
    let whole = whole_trajectory(runs);
    if !whole.is_empty() {
        s.push_str(&trajectory_markdown(&whole, min_success));
    }
    s
}

/// One run's mean `(Nav. Time, Disc.)` over all its good snapshots: the policies it passed
/// through, none chosen.
#[derive(Debug, Clone, PartialEq)]
pub struct RunMean {
    pub seed: u64,
    pub snapshots: usize,
    pub nav_time: f64,
    pub disc: f64,
}

/// One setting's whole-trajectory comparison.
#[derive(Debug, Clone, PartialEq)]
pub struct Trajectory {
    pub setting: Setting,
    /// Per method (in name order), its runs' means (in the order given).
    pub methods: Vec<(String, Vec<RunMean>)>,
}

/// Per setting (in [`Setting::ALL`] order) and method, each run's mean over its good snapshots;
/// runs without one are left out.
pub fn whole_trajectory(runs: &[RunSnapshots]) -> Vec<Trajectory> {
    let mut by_setting: BTreeMap<usize, BTreeMap<String, Vec<RunMean>>> = BTreeMap::new();
    for r in runs {
        let pts: Vec<(f64, f64)> = r.good.iter().filter_map(point).collect();
        if pts.is_empty() {
            continue;
        }
        let n = pts.len() as f64;
        by_setting
            .entry(r.setting.index())
            .or_default()
            .entry(r.method.clone())
            .or_default()
            .push(RunMean {
                seed: r.seed,
                snapshots: pts.len(),
                nav_time: pts.iter().map(|p| p.0).sum::<f64>() / n,
                disc: pts.iter().map(|p| p.1).sum::<f64>() / n,
            });
    }
    by_setting
        .into_iter()
        .map(|(i, methods)| Trajectory {
            setting: Setting::ALL[i],
            methods: methods.into_iter().collect(),
        })
        .collect()
}

fn trajectory_markdown(whole: &[Trajectory], min_success: f64) -> String {
    let mut s = format!(
        "\n## The whole trajectory\n\nEach run's mean over all its snapshots above (after the ε decay, validation success ≥ {min_success}; `--min-success 0` takes every validation after the decay): the policies the run passed through, none chosen. Mean ± std over runs; per run Disc. in the order the runs were given; Welch's test for every pair of methods of a setting with two runs or more each.\n\n| setting | method | runs | snapshots | Nav. Time (s) | Disc. | Disc. per run (seed) |\n|---|---|---|---|---|---|---|\n"
    );
    let mut tests = String::new();
    for t in whole {
        for (method, means) in &t.methods {
            let navs: Vec<f64> = means.iter().map(|m| m.nav_time).collect();
            let discs: Vec<f64> = means.iter().map(|m| m.disc).collect();
            let per_run: Vec<String> = means
                .iter()
                .map(|m| format!("{:.3} ({})", m.disc, m.seed))
                .collect();
            let _ = writeln!(
                s,
                "| {} | {method} | {} | {} | {} | {} | {} |",
                t.setting.name(),
                means.len(),
                means.iter().map(|m| m.snapshots).sum::<usize>(),
                mean_std_cell(&navs, 2),
                mean_std_cell(&discs, 3),
                per_run.join(", ")
            );
        }
        for (i, (a, ma)) in t.methods.iter().enumerate() {
            for (b, mb) in &t.methods[i + 1..] {
                let of =
                    |ms: &[RunMean], f: fn(&RunMean) -> f64| ms.iter().map(f).collect::<Vec<_>>();
                let (Some(wd), Some(wn)) = (
                    welch(&of(ma, |m| m.disc), &of(mb, |m| m.disc)),
                    welch(&of(ma, |m| m.nav_time), &of(mb, |m| m.nav_time)),
                ) else {
                    continue;
                };
                let _ = writeln!(
                    tests,
                    "- {}: {a} − {b}: Disc. {:+.3} (Welch p = {:.2}), Nav. Time {:+.2} s (p = {:.2})",
                    t.setting.name(),
                    wd.difference,
                    wd.p,
                    wn.difference,
                    wn.p
                );
            }
        }
    }
    if !tests.is_empty() {
        s.push('\n');
        s.push_str(&tests);
    }
    s
}

/// A least-squares line of Disc. on Nav. Time through one run's good snapshots.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LineFit {
    pub intercept: f64,
    pub slope: f64,
}

impl LineFit {
    /// The fitted Disc. at `nav_time`.
    pub fn at(self, nav_time: f64) -> f64 {
        self.intercept + self.slope * nav_time
    }

    /// The line through `points`; `None` below three points or when Nav. Time does not vary.
    pub fn through(points: &[(f64, f64)]) -> Option<Self> {
        if points.len() < 3 {
            return None;
        }
        let n = points.len() as f64;
        let mx = points.iter().map(|p| p.0).sum::<f64>() / n;
        let my = points.iter().map(|p| p.1).sum::<f64>() / n;
        let sxx: f64 = points.iter().map(|p| (p.0 - mx).powi(2)).sum();
        if sxx.is_nan() || sxx <= 1e-12 {
            return None;
        }
        let slope = points.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum::<f64>() / sxx;
        Some(Self {
            intercept: my - slope * mx,
            slope,
        })
    }
}

/// `runs` grouped by setting (keyed by [`Setting::index`]), in the order given.
fn by_setting(runs: &[RunSnapshots]) -> BTreeMap<usize, Vec<&RunSnapshots>> {
    let mut by: BTreeMap<usize, Vec<&RunSnapshots>> = BTreeMap::new();
    for r in runs {
        by.entry(r.setting.index()).or_default().push(r);
    }
    by
}

/// The median Nav. Time over every good snapshot of `runs`: the common speed of a setting.
fn median_nav_time<'a>(runs: impl IntoIterator<Item = &'a RunSnapshots>) -> Option<f64> {
    let mut navs: Vec<f64> = runs
        .into_iter()
        .flat_map(|r| r.good.iter().filter_map(point).map(|p| p.0))
        .collect();
    navs.sort_by(f64::total_cmp);
    match navs.len() {
        0 => None,
        n if n % 2 == 1 => Some(navs[n / 2]),
        n => Some(0.5 * (navs[n / 2 - 1] + navs[n / 2])),
    }
}

/// How [`common_speed_picks`] chose a run's snapshot.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PickHow {
    /// The gentlest good snapshot at or below the common speed.
    Gentlest,
    /// No good snapshot at or below it: the fastest good one.
    Fastest,
    /// No good snapshot at all: what the run's own `train.select` ships (`None`: its last
    /// weights).
    OwnRule,
}

impl PickHow {
    pub fn name(self) -> &'static str {
        match self {
            Self::Gentlest => "gentlest-at-or-below",
            Self::Fastest => "fastest",
            Self::OwnRule => "own-rule",
        }
    }
}

/// One run's snapshot chosen at its setting's common speed.
#[derive(Debug, Clone, PartialEq)]
pub struct SpeedPick<'a> {
    pub run: &'a RunSnapshots,
    /// The setting's common speed T*: the median validation Nav. Time of the good snapshots of
    /// every run given in the setting (`None` when none has one).
    pub nav_time: Option<f64>,
    pub pick: Option<&'a Validation>,
    pub how: PickHow,
}

/// The common-speed choice of Experiment 15 (`docs/REPRODUCTION.md`), one per run in the order
/// given: in each setting T* is the median validation Nav. Time of the good snapshots of all
/// runs given there (every method's); a run takes its good snapshot of lowest validation Disc.
/// among those no slower than T* (ties: the faster, then the earlier), else its fastest good
/// snapshot, else its own rule's choice. Every method is thus shipped at about the same speed,
/// chosen on validation seeds alone.
pub fn common_speed_picks(runs: &[RunSnapshots]) -> Vec<SpeedPick<'_>> {
    let medians: BTreeMap<usize, Option<f64>> = by_setting(runs)
        .into_iter()
        .map(|(i, rs)| (i, median_nav_time(rs)))
        .collect();
    runs.iter()
        .map(|r| {
            let nav_time = medians[&r.setting.index()];
            // (Disc., Nav. Time, RL episodes) of each good snapshot that has both.
            let keyed: Vec<((f64, f64, u64), &Validation)> = r
                .good
                .iter()
                .filter_map(|v| point(v).map(|(nav, disc)| ((disc, nav, v.rl_episodes), v)))
                .collect();
            let at_or_below = nav_time.and_then(|t| {
                keyed
                    .iter()
                    .filter(|(k, _)| k.1 <= t)
                    .min_by(|(a, _), (b, _)| {
                        a.0.total_cmp(&b.0)
                            .then(a.1.total_cmp(&b.1))
                            .then(a.2.cmp(&b.2))
                    })
            });
            let fastest = keyed
                .iter()
                .min_by(|(a, _), (b, _)| a.1.total_cmp(&b.1).then(a.2.cmp(&b.2)));
            let (pick, how) = match (at_or_below, fastest) {
                (Some(&(_, v)), _) => (Some(v), PickHow::Gentlest),
                (None, Some(&(_, v))) => (Some(v), PickHow::Fastest),
                (None, None) => (r.chosen.as_ref(), PickHow::OwnRule),
            };
            SpeedPick {
                run: r,
                nav_time,
                pick,
                how,
            }
        })
        .collect()
}

/// One setting's comparison at a common speed.
#[derive(Debug, Clone, PartialEq)]
pub struct CommonSpeed {
    pub setting: Setting,
    /// The median Nav. Time over every good snapshot of every run in the setting.
    pub nav_time: f64,
    /// Per method (in name order), its runs' lines.
    pub methods: Vec<(String, Vec<LineFit>)>,
}

/// Per setting (in [`Setting::ALL`] order), the methods' runs' Disc. lines and the common Nav.
/// Time to read them at; settings without a fitted run are left out.
pub fn at_common_speed(runs: &[RunSnapshots]) -> Vec<CommonSpeed> {
    by_setting(runs)
        .into_iter()
        .filter_map(|(i, rs)| {
            let nav_time = median_nav_time(rs.iter().copied())?;
            let mut methods: BTreeMap<String, Vec<LineFit>> = BTreeMap::new();
            for r in rs {
                let pts: Vec<(f64, f64)> = r.good.iter().filter_map(point).collect();
                if let Some(fit) = LineFit::through(&pts) {
                    methods.entry(r.method.clone()).or_default().push(fit);
                }
            }
            (!methods.is_empty()).then(|| CommonSpeed {
                setting: Setting::ALL[i],
                nav_time,
                methods: methods.into_iter().collect(),
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn line(ep: u64, success: f64, nav: f64, disc: f64) -> String {
        format!(
            "{{\"phase\":\"validation\",\"episode\":{ep},\"success_rate\":{success},\"collision_rate\":0.0,\"timeout_rate\":0.0,\"discomfort\":{disc},\"nav_time_s\":{nav}}}\n"
        )
    }

    fn run_dir(dir: &Path, method: &str, setting: &str, lines: &[String]) -> PathBuf {
        let run = dir.join(format!("{method}-{setting}-s1"));
        std::fs::create_dir_all(select::snapshot_dir(&run)).unwrap();
        std::fs::write(
            run.join("config.toml"),
            format!(
                "[run]\nmethod = \"{method}\"\nsetting = \"{setting}\"\nseed = 1\n[train]\nselect = \"low-disc\"\n[train.rl]\nepsilon_decay_episodes = 200\n"
            ),
        )
        .unwrap();
        std::fs::write(run.join("metrics.jsonl"), lines.concat()).unwrap();
        for ep in [0, 200, 400, 600, 800] {
            std::fs::write(select::snapshot_path(&run, ep), b"x").unwrap();
        }
        run
    }

    #[test]
    fn only_good_snapshots_after_the_decay_count_and_reaching_needs_both() {
        let dir = tempfile::tempdir().unwrap();
        // The paper's FSRL env2-invisible row: 10.92 s, Disc. 0.07.
        let run = run_dir(
            dir.path(),
            "fsrl",
            "env2-invisible",
            &[
                line(0, 1.0, 9.0, 0.01),     // before the decay ends
                line(200, 0.96, 10.5, 0.09), // fast, not gentle
                line(400, 0.99, 10.9, 0.06), // both: reaches
                line(600, 0.90, 10.0, 0.01), // success below 0.95
                line(800, 0.97, 12.0, 0.03), // gentle, slow; the gentlest: low-disc ships it
            ],
        );
        let r = read_run(&run, &Assumed::default(), 0.95).unwrap();
        assert_eq!(r.setting.name(), "env2-invisible");
        assert_eq!(
            r.good.iter().map(|v| v.rl_episodes).collect::<Vec<_>>(),
            [200, 400, 800]
        );
        assert_eq!(r.chosen.as_ref().map(|v| v.rl_episodes), Some(800));
        assert_eq!(r.paper(), Some((10.92, 0.07)));
        let reach: Vec<u64> = r.reaching_paper().iter().map(|v| v.rl_episodes).collect();
        assert_eq!(reach, [400]);
        let md = markdown(std::slice::from_ref(&r), 0.95);
        assert!(md.contains("| 10.50 s / 0.090 (ep 200) | 12.00 s / 0.030 (ep 800) | 12.00 s / 0.030 (ep 800) | 10.92 s / 0.07 | 1 |"), "{md}");
        assert!(md.contains("1 of 3 snapshots in 1 runs"), "{md}");
        let fig = figure(&[r], None, 0.95);
        assert_eq!(fig.panels.len(), 1);
        assert_eq!(fig.panels[0].groups[0].points.len(), 3);
        assert_eq!(fig.panels[0].groups[0].chosen, [(12.0, 0.03)]);
    }

    #[test]
    fn methods_are_compared_at_the_median_speed_of_all_their_snapshots() {
        let fit = LineFit::through(&[(10.0, 0.10), (11.0, 0.08), (12.0, 0.06)]).unwrap();
        assert!((fit.slope + 0.02).abs() < 1e-12 && (fit.at(11.5) - 0.07).abs() < 1e-12);
        assert_eq!(LineFit::through(&[(10.0, 0.1), (11.0, 0.2)]), None);
        assert_eq!(
            LineFit::through(&[(10.0, 0.1), (10.0, 0.2), (10.0, 0.3)]),
            None
        );
        let run = |method: &str, seed: u64, shift: f64| RunSnapshots {
            run: PathBuf::from(format!("{method}-s{seed}")),
            method: method.into(),
            setting: "env2-visible".parse().unwrap(),
            seed,
            good: [10.0, 11.0, 12.0]
                .iter()
                .enumerate()
                .map(|(k, &nav)| Validation {
                    rl_episodes: 2000 + 250 * k as u64,
                    success: 1.0,
                    collision: 0.0,
                    disc: Some(0.3 - 0.02 * nav + shift),
                    nav_time_s: Some(nav + seed as f64 * 0.5),
                    mean_return: None,
                })
                .collect(),
            chosen: None,
        };
        // FSRL 0.01 below SARL's line at every speed; SARL's runs are the slower ones.
        let runs = [
            run("fsrl", 0, -0.01),
            run("fsrl", 1, -0.012),
            run("sarl", 2, 0.0),
            run("sarl", 3, 0.002),
        ];
        let c = at_common_speed(&runs);
        assert_eq!(c.len(), 1);
        // 12 snapshot times: 10, 11, 12, 10.5, 11.5, 12.5, 11, 12, 13, 11.5, 12.5, 13.5.
        assert!((c[0].nav_time - 11.75).abs() < 1e-12, "{}", c[0].nav_time);
        let md = markdown(&runs, 0.95);
        assert!(md.contains("| env2-visible | 11.75 | fsrl | 2 |"), "{md}");
        // The whole trajectory: FSRL's runs average Disc. 0.3 − 0.02·11 − 0.011 = 0.069 at
        // 11.25 s (seeds 0 and 1 shift its times by 0 and 0.5 s); SARL's 0.081 at 12.25 s.
        let w = whole_trajectory(&runs);
        assert_eq!(w.len(), 1);
        let fsrl = &w[0].methods[0];
        assert_eq!((fsrl.0.as_str(), fsrl.1.len()), ("fsrl", 2));
        assert!(
            (fsrl.1[0].disc - 0.070).abs() < 1e-12 && (fsrl.1[1].nav_time - 11.5).abs() < 1e-12
        );
        assert!(md.contains("| env2-visible | fsrl | 2 | 6 | 11.25 ± 0.35 | 0.069 ± 0.001 | 0.070 (0), 0.068 (1) |"), "{md}");
        assert!(
            md.contains("- env2-visible: fsrl − sarl: Disc. -0.012"),
            "{md}"
        );
        assert!(md.contains("Nav. Time -1.00 s"), "{md}");
        assert!(md.contains("- env2-visible: fsrl − sarl = "), "{md}");
        let (f, s) = (&c[0].methods[0].1, &c[0].methods[1].1);
        let diff = f[0].at(11.75) - s[0].at(11.75);
        assert!(
            diff < -0.009,
            "{diff}: compared at the same speed, not at each run's own"
        );
    }

    #[test]
    fn the_common_speed_pick_is_the_gentlest_no_slower_than_the_median_of_all_runs() {
        let v = |ep: u64, nav: f64, disc: f64| Validation {
            rl_episodes: ep,
            success: 1.0,
            collision: 0.0,
            disc: Some(disc),
            nav_time_s: Some(nav),
            mean_return: None,
        };
        let run = |method: &str, setting: &str, good: Vec<Validation>, chosen| RunSnapshots {
            run: PathBuf::from(format!("{method}-{setting}")),
            method: method.into(),
            setting: setting.parse().unwrap(),
            seed: 0,
            good,
            chosen,
        };
        let runs = [
            // Times 10, 11, 12 and 11.5, 12.5, 13: the median of the six is 11.75 s.
            run(
                "fsrl",
                "env2-visible",
                vec![
                    v(2000, 10.0, 0.09),
                    v(2250, 11.0, 0.05),
                    v(2500, 12.0, 0.01),
                ],
                None,
            ),
            run(
                "sarl",
                "env2-visible",
                vec![
                    v(2000, 13.0, 0.01),
                    v(2250, 12.5, 0.02),
                    v(2500, 11.5, 0.07),
                ],
                None,
            ),
            // The only run with snapshots in its setting: T* is its own median (11 s); of its
            // two equally gentle snapshots at or below it, the faster.
            run(
                "sarl",
                "env1-invisible",
                vec![
                    v(2000, 11.0, 0.03),
                    v(2250, 12.0, 0.01),
                    v(2500, 10.0, 0.03),
                ],
                None,
            ),
            // No good snapshot: the run's own rule.
            run("fsrl", "env1-invisible", vec![], Some(v(4000, 14.0, 0.2))),
        ];
        let picks = common_speed_picks(&runs);
        let got: Vec<(Option<u64>, PickHow)> = picks
            .iter()
            .map(|p| (p.pick.map(|v| v.rl_episodes), p.how))
            .collect();
        assert_eq!(
            got,
            [
                (Some(2250), PickHow::Gentlest),
                (Some(2500), PickHow::Gentlest),
                (Some(2500), PickHow::Gentlest),
                (Some(4000), PickHow::OwnRule),
            ]
        );
        assert_eq!(picks[0].nav_time, Some(11.75));
        assert_eq!(picks[2].nav_time, Some(11.0));
        // A setting whose every snapshot is slower than the median of another's: the fastest.
        let slow = [
            run(
                "fsrl",
                "env3-visible",
                vec![v(2000, 12.0, 0.05), v(2250, 13.0, 0.01)],
                None,
            ),
            run(
                "sarl",
                "env3-visible",
                vec![v(2000, 10.0, 0.2), v(2250, 10.5, 0.1)],
                None,
            ),
        ];
        let picks = common_speed_picks(&slow);
        assert_eq!(picks[0].nav_time, Some(11.25));
        assert_eq!(
            (picks[0].pick.map(|v| v.rl_episodes), picks[0].how),
            (Some(2000), PickHow::Fastest)
        );
        assert_eq!(picks[1].pick.map(|v| v.rl_episodes), Some(2250));
    }

    #[test]
    fn a_directory_without_a_config_needs_all_three_assumptions() {
        let dir = tempfile::tempdir().unwrap();
        let err = read_run(dir.path(), &Assumed::default(), 0.95)
            .unwrap_err()
            .to_string();
        assert!(err.contains("not a run directory"), "{err}");
        let run = dir.path().join("fsrl-paper-s2");
        std::fs::create_dir_all(&run).unwrap();
        std::fs::write(
            run.join("metrics.jsonl"),
            [line(1000, 1.0, 11.0, 0.02), line(2000, 0.99, 12.0, 0.05)].concat(),
        )
        .unwrap();
        let mut assumed = Assumed {
            method: Some("fsrl".into()),
            setting: Some("env1-invisible".into()),
            decay_end: None,
        };
        let err = read_run(&run, &assumed, 0.95).unwrap_err().to_string();
        assert!(
            err.contains("pass --method, --setting and --decay-end"),
            "{err}"
        );
        assumed.decay_end = Some(1500);
        let r = read_run(&run, &assumed, 0.95).unwrap();
        assert_eq!((r.seed, r.good.len(), r.chosen.clone()), (2, 1, None));
        assert_eq!(r.paper(), Some((10.90, 0.01)));
        assumed.setting = Some("env4".into());
        assert!(read_run(&run, &assumed, 0.95).is_err());
    }
}
