//! `fsrl plot frontier`: the policies runs passed through, each validated snapshot as a point of
//! (Nav. Time, Disc.), beside the paper's row of its method and setting. Answers whether another
//! snapshot of the same runs could have shipped the paper's point: as fast *and* as gentle
//! (`docs/REPRODUCTION.md`, Experiment 13). Only the snapshots `low-disc` may choose from take
//! part: after the ε decay, validation success at least [`LOW_DISC_MIN_SUCCESS`]. Validation
//! seeds only; 100 episodes a validation, so a point is uncertain by about ±0.5 s and ±0.02 Disc.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use policy::method::{Select, LOW_DISC_MIN_SUCCESS};
use sim::Setting;

use crate::config::FileConfig;
use crate::report::Metric;
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
pub fn read_run(run: &Path, assumed: &Assumed) -> anyhow::Result<RunSnapshots> {
    let config_path = run.join("config.toml");
    let metrics = run.join("metrics.jsonl");
    let (method, setting, seed, decay_end, rule) = if config_path.is_file() {
        let c = FileConfig::load(Some(&config_path))?;
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
            "{}: not a run directory (no config.toml or metrics.jsonl; `fsrl plot frontier` takes the run directories of `fsrl train --single-process` or `fsrl reproduce`)",
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
    let chosen = match rule {
        Select::Last => None,
        rule => select::chosen_snapshot(run, rule, decay_end)?.map(|(v, _)| v),
    };
    Ok(RunSnapshots {
        run: run.to_path_buf(),
        method,
        setting,
        seed,
        good: select::validations(&text)
            .into_iter()
            .filter(|v| select::good_after(v, decay_end) && point(v).is_some())
            .collect(),
        chosen,
    })
}

/// The figure: one panel per setting (in [`Setting::ALL`] order), one group per method.
pub fn figure(runs: &[RunSnapshots], title: Option<String>) -> viz::Frontier {
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
            "snapshots after the ε decay with validation success ≥ {LOW_DISC_MIN_SUCCESS} (100 validation episodes each); below and left of × is as fast and as gentle as the paper"
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
pub fn markdown(runs: &[RunSnapshots]) -> String {
    let mut s = format!(
        "Validated snapshots (after the ε decay, validation success ≥ {LOW_DISC_MIN_SUCCESS}): Nav. Time (s) / Disc. on the validation seeds. \"Reach\": snapshots at least as fast and as gentle as the paper's row.\n\n| run | method | setting | seed | snapshots | fastest | gentlest | shipped | paper | reach |\n|---|---|---|---|---|---|---|---|---|---|\n"
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
    s
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
        let r = read_run(&run, &Assumed::default()).unwrap();
        assert_eq!(r.setting.name(), "env2-invisible");
        assert_eq!(
            r.good.iter().map(|v| v.rl_episodes).collect::<Vec<_>>(),
            [200, 400, 800]
        );
        assert_eq!(r.chosen.as_ref().map(|v| v.rl_episodes), Some(800));
        assert_eq!(r.paper(), Some((10.92, 0.07)));
        let reach: Vec<u64> = r.reaching_paper().iter().map(|v| v.rl_episodes).collect();
        assert_eq!(reach, [400]);
        let md = markdown(std::slice::from_ref(&r));
        assert!(md.contains("| 10.50 s / 0.090 (ep 200) | 12.00 s / 0.030 (ep 800) | 12.00 s / 0.030 (ep 800) | 10.92 s / 0.07 | 1 |"), "{md}");
        assert!(md.contains("1 of 3 snapshots in 1 runs"), "{md}");
        let fig = figure(&[r], None);
        assert_eq!(fig.panels.len(), 1);
        assert_eq!(fig.panels[0].groups[0].points.len(), 3);
        assert_eq!(fig.panels[0].groups[0].chosen, [(12.0, 0.03)]);
    }

    #[test]
    fn a_directory_without_a_config_needs_all_three_assumptions() {
        let dir = tempfile::tempdir().unwrap();
        let err = read_run(dir.path(), &Assumed::default())
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
        let err = read_run(&run, &assumed).unwrap_err().to_string();
        assert!(
            err.contains("pass --method, --setting and --decay-end"),
            "{err}"
        );
        assumed.decay_end = Some(1500);
        let r = read_run(&run, &assumed).unwrap();
        assert_eq!((r.seed, r.good.len(), r.chosen.clone()), (2, 1, None));
        assert_eq!(r.paper(), Some((10.90, 0.01)));
        assumed.setting = Some("env4".into());
        assert!(read_run(&run, &assumed).is_err());
    }
}
