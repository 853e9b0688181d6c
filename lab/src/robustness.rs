//! Issue 54's robustness table: trained policies tested, without retraining, in crowds other
//! than their own: 5, 10, 15 and 20 moving people, all ORCA or all social force
//! ([`VARIANTS`]). Each policy is tested in the setting it was trained in, the ORCA robot in all
//! six; [`run`] writes one `fsrl eval` report per variant and setting (`DIR/<variant>/<setting>/`;
//! the policies a report already holds on the same seeds and crowd are kept and not evaluated
//! again, the others are added one by one: an interrupted run resumes, and a run with more
//! models adds their rows to the table instead of replacing it) and
//! [`Table::collect`] reads them back into one table, the mean over each method's seeds.

use std::collections::BTreeMap;
use std::fmt::Write;
use std::path::{Path, PathBuf};

use anyhow::Context;
use serde::Serialize;
use sim::{CrowdModel, Setting, SimConfig};

use crate::evaluation::{evaluate_orca, Crowd, EvalPlan, LoadedPolicy};
use crate::report::{EvalReport, EVAL_KIND};

/// One crowd of the table.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Variant {
    pub people: usize,
    pub model: CrowdModel,
}

/// The table's columns: 5/10/15/20 moving people × ORCA / social force.
pub const VARIANTS: [Variant; 8] = {
    let orca = CrowdModel::Orca;
    let sf = CrowdModel::SocialForce;
    [
        Variant {
            people: 5,
            model: orca,
        },
        Variant {
            people: 10,
            model: orca,
        },
        Variant {
            people: 15,
            model: orca,
        },
        Variant {
            people: 20,
            model: orca,
        },
        Variant {
            people: 5,
            model: sf,
        },
        Variant {
            people: 10,
            model: sf,
        },
        Variant {
            people: 15,
            model: sf,
        },
        Variant {
            people: 20,
            model: sf,
        },
    ]
};

impl Variant {
    /// The directory of its reports: `orca-5`, `social-force-20`.
    pub fn dir_name(&self) -> String {
        format!("{}-{}", self.model, self.people)
    }

    pub fn crowd(&self) -> Crowd {
        Crowd {
            people: Some(self.people),
            model: Some(self.model),
        }
    }

    /// A column heading: "5 ORCA", "20 SF".
    pub fn heading(&self) -> String {
        let model = match self.model {
            CrowdModel::Orca => "ORCA",
            CrowdModel::SocialForce => "SF",
            CrowdModel::Mixed => "mixed",
        };
        format!("{} {model}", self.people)
    }
}

/// What [`run`] evaluates.
pub struct Plan<'a> {
    pub policies: &'a [LoadedPolicy],
    /// Also the ORCA robot, in `orca_sim` (all six settings).
    pub orca_sim: Option<&'a SimConfig>,
    pub episodes: u32,
    pub seed_start: u64,
    pub threads: usize,
}

/// Evaluates every policy in its own setting and the ORCA robot in the six, in every variant,
/// into `dir/<variant>/<setting or orca>/eval.*`. `progress` hears each report's name before it
/// runs and `done` each episode. Reports already there for the same policies (by SHA-256) and
/// episodes are kept.
pub fn run(
    plan: &Plan<'_>,
    dir: &Path,
    progress: &dyn Fn(&str, u64),
    done: &(dyn Fn() + Sync),
) -> anyhow::Result<()> {
    let mut by_setting: BTreeMap<usize, (Setting, Vec<&LoadedPolicy>)> = BTreeMap::new();
    for p in plan.policies {
        let s = p.model.setting;
        if !s.is_paper() {
            anyhow::bail!(
                "{}: trained in {s}; the robustness table changes the crowds of the paper's six \
                 settings only",
                p.path.display()
            );
        }
        by_setting
            .entry(s.index())
            .or_insert((s, Vec::new()))
            .1
            .push(p);
    }
    for variant in VARIANTS {
        let base = EvalPlan {
            settings: Vec::new(),
            seed_start: plan.seed_start,
            episodes: plan.episodes,
            threads: plan.threads,
            orca_safety_space_m: 0.0,
            planning_top_k: None,
            planning_breadth: None,
            crowd: variant.crowd(),
            shield_s: None,
            progress_tolerance: None,
        };
        let report = |subjects| EvalReport {
            kind: EVAL_KIND.into(),
            test_seed_start: plan.seed_start,
            episodes_per_setting: plan.episodes,
            crowd: variant.crowd().label(),
            subjects,
        };
        for (setting, policies) in by_setting.values() {
            let out = dir.join(variant.dir_name()).join(setting.name());
            let mut subjects = earlier_subjects(&out, plan, &variant.crowd().label());
            let missing: Vec<&LoadedPolicy> = policies
                .iter()
                .copied()
                .filter(|p| {
                    !subjects
                        .iter()
                        .any(|s| s.checkpoint_sha256.as_deref() == Some(p.sha256.as_str()))
                })
                .collect();
            if missing.is_empty() {
                continue;
            }
            let plan_s = EvalPlan {
                settings: vec![*setting],
                ..base.clone()
            };
            progress(
                &format!("{} {}", variant.dir_name(), setting),
                missing.len() as u64 * u64::from(plan.episodes),
            );
            for p in missing {
                subjects.push(p.evaluate(&plan_s, done)?);
                report(subjects.clone()).write(&out)?;
            }
        }
        if let Some(sim) = plan.orca_sim {
            let out = dir.join(variant.dir_name()).join("orca");
            if up_to_date(&out, plan, &variant.crowd().label()) {
                continue;
            }
            let plan_o = EvalPlan {
                settings: Setting::ALL.to_vec(),
                ..base.clone()
            };
            progress(
                &format!("{} orca", variant.dir_name()),
                Setting::ALL.len() as u64 * u64::from(plan.episodes),
            );
            report(vec![evaluate_orca(sim, &plan_o, done)?]).write(&out)?;
        }
    }
    Ok(())
}

/// The report in `out`, if it is one of these seeds, episodes and crowd.
fn earlier_report(out: &Path, plan: &Plan<'_>, crowd: &Option<String>) -> Option<EvalReport> {
    let text = std::fs::read_to_string(out.join("eval.json")).ok()?;
    let r = serde_json::from_str::<EvalReport>(&text).ok()?;
    (r.episodes_per_setting == plan.episodes
        && r.test_seed_start == plan.seed_start
        && &r.crowd == crowd)
        .then_some(r)
}

/// The policies' subjects `out/eval.json` already holds on these seeds and in this crowd (every
/// one of them, also those not among this run's models: their rows stay in the table); none if
/// the file is missing, unreadable, or of other seeds or another crowd.
fn earlier_subjects(
    out: &Path,
    plan: &Plan<'_>,
    crowd: &Option<String>,
) -> Vec<crate::report::SubjectReport> {
    earlier_report(out, plan, crowd)
        .map(|r| {
            r.subjects
                .into_iter()
                .filter(|s| s.checkpoint_sha256.is_some())
                .collect()
        })
        .unwrap_or_default()
}

/// Whether `out/eval.json` already holds the ORCA robot on these seeds.
fn up_to_date(out: &Path, plan: &Plan<'_>, crowd: &Option<String>) -> bool {
    earlier_report(out, plan, crowd)
        .is_some_and(|r| r.subjects.len() == 1 && r.subjects[0].method == "orca")
}

/// One cell: a method in a setting and a crowd, over its seeds.
#[derive(Debug, Clone, Serialize)]
pub struct Cell {
    /// Mean over the seeds (policies) of their success rates.
    pub success: f64,
    /// The lowest and highest seed's success.
    pub success_range: [f64; 2],
    pub collision: f64,
    pub timeout: f64,
    /// Mean over the seeds with a success of their mean Nav. Time.
    pub nav_time_s: Option<f64>,
    pub disc: f64,
    pub policies: usize,
    pub episodes: u32,
}

#[derive(Debug, Clone, Serialize)]
pub struct Row {
    pub method: String,
    pub setting: String,
    /// One per [`VARIANTS`] column (`None`: not evaluated).
    pub cells: Vec<Option<Cell>>,
}

/// The table [`Table::collect`] reads from a [`run`]'s directory.
#[derive(Debug, Clone, Serialize)]
pub struct Table {
    pub columns: Vec<String>,
    pub rows: Vec<Row>,
}

/// The order methods are listed in.
const METHOD_ORDER: [&str; 7] = [
    "orca",
    "lstm-rl",
    "sarl",
    "sarl+foresight",
    "sarl+efficiency",
    "fsrl",
    "fsrl-plan",
];

impl Table {
    /// Reads every `DIR/<variant>/*/eval.json`: each subject in the setting it was trained in
    /// (the ORCA robot in every setting), the mean over the subjects of one method.
    pub fn collect(dir: &Path) -> anyhow::Result<Table> {
        // (method rank, method, setting index) -> per-variant reports of the seeds
        type Key = (usize, String, usize);
        let mut acc: BTreeMap<Key, Vec<Vec<crate::report::SettingReport>>> = BTreeMap::new();
        let mut found = 0;
        for (v, variant) in VARIANTS.iter().enumerate() {
            let vdir = dir.join(variant.dir_name());
            let Ok(entries) = std::fs::read_dir(&vdir) else {
                continue;
            };
            let mut files: Vec<PathBuf> = entries
                .filter_map(|e| e.ok().map(|e| e.path().join("eval.json")))
                .filter(|p| p.is_file())
                .collect();
            files.sort();
            for file in files {
                let text = std::fs::read_to_string(&file)
                    .with_context(|| format!("cannot read {}", file.display()))?;
                let report: EvalReport = serde_json::from_str(&text)
                    .with_context(|| format!("{}: not an fsrl eval report", file.display()))?;
                found += 1;
                for subj in &report.subjects {
                    let rank = METHOD_ORDER
                        .iter()
                        .position(|m| *m == subj.method)
                        .unwrap_or(METHOD_ORDER.len());
                    for r in &subj.settings {
                        let Some(setting) = r.parsed_setting() else {
                            continue;
                        };
                        let own = subj.trained_setting.as_deref().unwrap_or(setting.name());
                        if own != setting.name() {
                            continue;
                        }
                        let key = (rank, subj.method.clone(), setting.index());
                        let cols = acc
                            .entry(key)
                            .or_insert_with(|| vec![Vec::new(); VARIANTS.len()]);
                        cols[v].push(r.clone());
                    }
                }
            }
        }
        if found == 0 {
            anyhow::bail!(
                "{}: no eval.json under any of {} (run `fsrl robustness MODELS --out {}` first)",
                dir.display(),
                VARIANTS.map(|v| v.dir_name()).join(", "),
                dir.display()
            );
        }
        let rows = acc
            .into_iter()
            .map(|((_, method, s), cols)| Row {
                method,
                setting: Setting::every()
                    .nth(s)
                    .map_or_else(String::new, |s| s.name().to_string()),
                cells: cols.iter().map(|reports| cell(reports)).collect(),
            })
            .collect();
        Ok(Table {
            columns: VARIANTS.iter().map(|v| v.heading()).collect(),
            rows,
        })
    }

    /// Success per method and setting (mean over seeds, the seeds' range beside it when there
    /// are several), then per method and metric the mean over its settings (`–`: a setting
    /// without a value, e.g. no success to time).
    pub fn markdown(&self) -> String {
        let mut s = String::new();
        let head = |s: &mut String, first: &str| {
            let _ = writeln!(s, "| {first} | {} |", self.columns.join(" | "));
            let _ = writeln!(s, "|---|{}", "---|".repeat(self.columns.len()));
        };
        let _ = writeln!(
            s,
            "### Success by setting (mean over seeds; [lowest, highest seed])\n"
        );
        head(&mut s, "method, trained setting");
        for row in &self.rows {
            let cells: Vec<String> = row
                .cells
                .iter()
                .map(|c| match c {
                    None => "–".into(),
                    Some(c) if c.policies > 1 => format!(
                        "{:.3} [{:.3}, {:.3}]",
                        c.success, c.success_range[0], c.success_range[1]
                    ),
                    Some(c) => format!("{:.3}", c.success),
                })
                .collect();
            let _ = writeln!(
                s,
                "| {} {} | {} |",
                row.method,
                row.setting,
                cells.join(" | ")
            );
        }
        for (title, pick, digits) in [
            (
                "Success",
                (|c: &Cell| Some(c.success)) as fn(&Cell) -> Option<f64>,
                3,
            ),
            ("Collision rate", |c| Some(c.collision), 3),
            ("Timeout rate", |c| Some(c.timeout), 3),
            ("Nav. Time (s)", |c| c.nav_time_s, 2),
        ] {
            let _ = writeln!(
                s,
                "\n### {title}, mean over the settings each method was trained in (the ORCA \
                 robot: all six)\n"
            );
            head(&mut s, "method");
            for (method, means) in self.method_means(pick) {
                let cells: Vec<String> = means
                    .iter()
                    .map(|m| m.map_or("–".into(), |m| format!("{m:.digits$}")))
                    .collect();
                let _ = writeln!(s, "| {method} | {} |", cells.join(" | "));
            }
        }
        s
    }

    /// Per method (in table order), per column: the mean of `pick` over its settings, `None`
    /// unless every one of its settings has the column.
    pub fn method_means(&self, pick: fn(&Cell) -> Option<f64>) -> Vec<(String, Vec<Option<f64>>)> {
        let mut out: Vec<(String, Vec<Option<f64>>)> = Vec::new();
        let mut methods: Vec<&str> = Vec::new();
        for row in &self.rows {
            if !methods.contains(&row.method.as_str()) {
                methods.push(&row.method);
            }
        }
        for method in methods {
            let rows: Vec<&Row> = self.rows.iter().filter(|r| r.method == method).collect();
            let means = (0..self.columns.len())
                .map(|c| {
                    let vals: Option<Vec<f64>> = rows
                        .iter()
                        .map(|r| r.cells[c].as_ref().and_then(pick))
                        .collect();
                    vals.map(|v| v.iter().sum::<f64>() / v.len() as f64)
                })
                .collect();
            out.push((method.to_string(), means));
        }
        out
    }

    /// Writes robustness.md and robustness.json into `dir`.
    pub fn write(&self, dir: &Path) -> anyhow::Result<()> {
        for (name, text) in [
            ("robustness.md", self.markdown()),
            ("robustness.json", serde_json::to_string_pretty(self)?),
        ] {
            let path = dir.join(name);
            std::fs::write(&path, text)
                .with_context(|| format!("cannot write {}", path.display()))?;
        }
        Ok(())
    }
}

fn cell(reports: &[crate::report::SettingReport]) -> Option<Cell> {
    if reports.is_empty() {
        return None;
    }
    let n = reports.len() as f64;
    let mean = |f: fn(&crate::report::SettingReport) -> f64| reports.iter().map(f).sum::<f64>() / n;
    let nav: Vec<f64> = reports.iter().filter_map(|r| r.nav_time_s).collect();
    let lo = reports
        .iter()
        .map(|r| r.success)
        .fold(f64::INFINITY, f64::min);
    let hi = reports
        .iter()
        .map(|r| r.success)
        .fold(f64::NEG_INFINITY, f64::max);
    Some(Cell {
        success: mean(|r| r.success),
        success_range: [lo, hi],
        collision: mean(|r| r.collision),
        timeout: mean(|r| r.timeout),
        nav_time_s: (!nav.is_empty()).then(|| nav.iter().sum::<f64>() / nav.len() as f64),
        disc: mean(|r| r.disc),
        policies: reports.len(),
        episodes: reports.iter().map(|r| r.episodes).sum(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn variants_name_their_directories_and_columns() {
        let names: Vec<String> = VARIANTS.iter().map(|v| v.dir_name()).collect();
        assert_eq!(names[0], "orca-5");
        assert_eq!(names[7], "social-force-20");
        assert_eq!(VARIANTS[7].heading(), "20 SF");
        assert_eq!(
            VARIANTS[3].crowd().label().as_deref(),
            Some("20 moving people, orca people")
        );
    }

    #[test]
    fn an_empty_directory_is_an_error_that_says_what_to_run() {
        let dir = std::env::temp_dir().join(format!("fsrl-robustness-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let e = Table::collect(&dir).unwrap_err().to_string();
        std::fs::remove_dir_all(&dir).unwrap();
        assert!(
            e.contains("no eval.json") && e.contains("fsrl robustness"),
            "{e}"
        );
    }

    #[test]
    fn orca_runs_in_every_setting_and_a_table_reads_the_reports_back() {
        let dir = std::env::temp_dir().join(format!("fsrl-robustness-orca-{}", std::process::id()));
        let sim = SimConfig::default();
        let plan = Plan {
            policies: &[],
            orca_sim: Some(&sim),
            episodes: 2,
            seed_start: 1000,
            threads: 2,
        };
        let heard = std::sync::Mutex::new(Vec::new());
        run(
            &plan,
            &dir,
            &|name, _| heard.lock().unwrap().push(name.to_string()),
            &|| {},
        )
        .unwrap();
        assert_eq!(heard.lock().unwrap().len(), VARIANTS.len());
        // A second run finds every report up to date.
        run(
            &plan,
            &dir,
            &|name, _| heard.lock().unwrap().push(name.to_string()),
            &|| {},
        )
        .unwrap();
        assert_eq!(heard.lock().unwrap().len(), VARIANTS.len());
        let table = Table::collect(&dir).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
        assert_eq!(table.rows.len(), 6, "the ORCA robot in the six settings");
        for row in &table.rows {
            assert_eq!(row.method, "orca");
            assert!(row
                .cells
                .iter()
                .all(|c| c.as_ref().is_some_and(|c| c.episodes == 2)));
        }
        assert_eq!(table.rows[0].setting, "env1-invisible");
        let md = table.markdown();
        assert!(md.contains("| orca env1-invisible |"), "{md}");
        assert!(md.contains("20 SF"), "{md}");
    }
}
