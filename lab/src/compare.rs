//! `fsrl compare RUN...`'s analysis: one table across runs, methods × settings, mean ± std over the runs
//! (seeds) of each method, the paper's numbers beside ours where it has them.
//!
//! A source is a run directory (its `eval/eval.json` from `fsrl eval` when present, else the
//! `report.json` of `fsrl train`, which covers the trained setting only) or an `eval.json` file
//! (every policy in it, e.g. the ORCA baseline).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use serde::Serialize;
use sim::Setting;

use crate::report::{
    csv_field, mean_ci95, paper_layout_row, paper_row, welch, EvalReport, Metric, Report,
    SettingReport, SubjectReport, Welch, PAPER_COLUMNS,
};
use crate::run::RunFile;

/// One policy's results, read from a source.
pub struct Sourced {
    pub subject: SubjectReport,
}

fn read_json<T: serde::de::DeserializeOwned>(path: &Path) -> anyhow::Result<T> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    serde_json::from_str(&text)
        .with_context(|| format!("{}: not a report this build reads", path.display()))
}

fn read_eval(path: &Path) -> anyhow::Result<EvalReport> {
    let r: EvalReport = read_json(path)?;
    if r.kind != crate::report::EVAL_KIND {
        bail!(
            "{}: not an `fsrl eval` report (kind {:?})",
            path.display(),
            r.kind
        );
    }
    for subject in &r.subjects {
        check_subject(path, subject)?;
    }
    Ok(r)
}

/// Refuses a subject with a setting no evaluation can have written ([`SettingReport::check`]).
fn check_subject(path: &Path, subject: &SubjectReport) -> anyhow::Result<()> {
    for s in &subject.settings {
        if let Err(e) = s.check() {
            bail!(
                "{}: {}: {e}; not a report this build can average",
                path.display(),
                subject.label
            );
        }
    }
    Ok(())
}

/// Reads every source; see the module documentation.
pub fn load_sources(paths: &[PathBuf]) -> anyhow::Result<Vec<Sourced>> {
    let mut out = Vec::new();
    for path in paths {
        if path.is_dir() {
            let eval = path.join("eval").join("eval.json");
            let train = path.join("report.json");
            if eval.exists() {
                for subject in read_eval(&eval)?.subjects {
                    out.push(Sourced { subject });
                }
            } else if train.exists() {
                let r: Report = read_json(&train)?;
                let cfg = RunFile::load(&path.join("config.toml")).ok();
                let label = path
                    .canonicalize()
                    .ok()
                    .and_then(|p| p.file_name().map(|n| n.to_string_lossy().into_owned()))
                    .unwrap_or_else(|| path.display().to_string());
                eprintln!(
                    "note: {} has no eval/eval.json; using report.json (its trained setting only). `fsrl eval {}` scores all six settings.",
                    path.display(),
                    path.display()
                );
                let subject = SubjectReport {
                    label,
                    method: r.method,
                    checkpoint: Some(path.join("checkpoints").join("latest.ckpt"))
                        .filter(|c| c.exists())
                        .map(|c| c.display().to_string()),
                    checkpoint_sha256: None,
                    policy_version: r.policy_version,
                    run_seed: cfg.as_ref().map(|c| c.run.seed),
                    planning_top_k: cfg.as_ref().map_or(0, |c| c.train.planning_top_k),
                    planning_breadth: cfg.as_ref().map_or(0, |c| c.train.planning_breadth),
                    shield_s: cfg.as_ref().map_or(0.0, |c| c.train.shield_s),
                    progress_tolerance: cfg.as_ref().map_or(0.0, |c| c.train.progress_tolerance),
                    trained_setting: cfg.map(|c| c.run.setting),
                    settings: r.settings,
                };
                check_subject(&train, &subject)?;
                out.push(Sourced { subject });
            } else {
                bail!(
                    "{}: neither eval/eval.json nor report.json (run `fsrl eval {}` first)",
                    path.display(),
                    path.display()
                );
            }
        } else if path.exists() {
            for subject in read_eval(path)?.subjects {
                out.push(Sourced { subject });
            }
        } else {
            bail!("{}: no such run directory or eval.json", path.display());
        }
    }
    Ok(out)
}

/// The runs of one method.
pub struct Group {
    pub method: String,
    pub members: Vec<SubjectReport>,
}

const ORDER: [&str; 6] = [
    "orca",
    "lstm-rl",
    "sarl",
    "sarl+foresight",
    "sarl+efficiency",
    "fsrl",
];

/// Groups policies by method, in the paper's order (unknown methods last).
pub fn group(sources: Vec<Sourced>) -> Vec<Group> {
    // The same checkpoint met twice (a run directory and an eval.json holding it) counts once,
    // with the record covering more settings.
    let key = |s: &SubjectReport| {
        s.checkpoint.as_ref().map(|c| {
            (
                std::fs::canonicalize(c).map_or_else(|_| c.clone(), |p| p.display().to_string()),
                s.policy_version,
            )
        })
    };
    let mut unique: Vec<Sourced> = Vec::new();
    for s in sources {
        let k = key(&s.subject);
        match unique
            .iter_mut()
            .find(|u| k.is_some() && key(&u.subject) == k)
        {
            Some(u) => {
                eprintln!("note: {} is listed twice; counted once", s.subject.label);
                if s.subject.settings.len() > u.subject.settings.len() {
                    *u = s;
                }
            }
            None => unique.push(s),
        }
    }
    let mut groups: Vec<Group> = Vec::new();
    for s in unique {
        match groups.iter_mut().find(|g| g.method == s.subject.method) {
            Some(g) => g.members.push(s.subject),
            None => groups.push(Group {
                method: s.subject.method.clone(),
                members: vec![s.subject],
            }),
        }
    }
    let rank = |m: &str| ORDER.iter().position(|o| *o == m).unwrap_or(ORDER.len());
    groups.sort_by_key(|g| rank(&g.method));
    groups
}

/// Mean and standard deviation over runs.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Stat {
    pub mean: f64,
    /// Sample standard deviation over runs; null for a single run.
    pub std: Option<f64>,
    pub n: usize,
}

impl Stat {
    pub fn of(xs: &[f64]) -> Option<Stat> {
        let (mean, std) = crate::report::mean_std(xs)?;
        Some(Stat {
            mean,
            std,
            n: xs.len(),
        })
    }

    fn text(&self, digits: usize) -> String {
        match self.std {
            Some(s) => format!("{:.digits$} ± {s:.digits$}", self.mean),
            None => format!("{:.digits$}", self.mean),
        }
    }
}

impl Group {
    pub fn values(&self, metric: Metric, setting: Setting) -> Vec<f64> {
        self.members
            .iter()
            .filter_map(|m| m.setting(setting))
            .filter_map(|r| metric.of(r).map(|v| v.0))
            .collect()
    }

    pub fn stat(&self, metric: Metric, setting: Setting) -> Option<Stat> {
        Stat::of(&self.values(metric, setting))
    }

    /// The most runs any one setting has: all of them when every run is evaluated on all six
    /// settings, the seeds when each run covers only the setting it was trained in (the grid of
    /// `fsrl reproduce`).
    pub fn runs_per_setting(&self) -> usize {
        self.runs_by_setting().max().unwrap_or(0)
    }

    /// How many runs have a result on each setting that has any.
    pub fn runs_by_setting(&self) -> impl Iterator<Item = usize> + '_ {
        Setting::ALL
            .iter()
            .map(|&s| {
                self.members
                    .iter()
                    .filter(|m| m.setting(s).is_some())
                    .count()
            })
            .filter(|&n| n > 0)
    }

    /// The member's own record when the group has exactly one run with this setting.
    pub fn single(&self, setting: Setting) -> Option<&SettingReport> {
        let mut it = self.members.iter().filter_map(|m| m.setting(setting));
        let first = it.next()?;
        it.next().is_none().then_some(first)
    }
}

#[derive(Serialize)]
struct CellJson {
    setting: String,
    runs: usize,
    success: Option<Stat>,
    collision: Option<Stat>,
    timeout: Option<Stat>,
    nav_time_s: Option<Stat>,
    disc: Option<Stat>,
    path_length_m: Option<Stat>,
    mean_abs_rotation_rad: Option<Stat>,
    mean_return: Option<Stat>,
    paper_nav_time_s: Option<f64>,
    paper_disc: Option<f64>,
}

#[derive(Serialize)]
struct GroupJson {
    method: String,
    runs: Vec<String>,
    settings: Vec<CellJson>,
}

#[derive(Serialize)]
struct CompareJson {
    kind: &'static str,
    groups: Vec<GroupJson>,
}

fn to_json(groups: &[Group]) -> CompareJson {
    CompareJson {
        kind: "fsrl compare",
        groups: groups
            .iter()
            .map(|g| GroupJson {
                method: g.method.clone(),
                runs: g.members.iter().map(|m| m.label.clone()).collect(),
                settings: Setting::ALL
                    .iter()
                    .map(|&s| CellJson {
                        setting: s.name().into(),
                        runs: g.values(Metric::Success, s).len(),
                        success: g.stat(Metric::Success, s),
                        collision: g.stat(Metric::Collision, s),
                        timeout: g.stat(Metric::Timeout, s),
                        nav_time_s: g.stat(Metric::NavTime, s),
                        disc: g.stat(Metric::Disc, s),
                        path_length_m: g.stat(Metric::PathLength, s),
                        mean_abs_rotation_rad: g.stat(Metric::Smoothness, s),
                        mean_return: g.stat(Metric::Return, s),
                        paper_nav_time_s: Metric::NavTime.paper(&g.method, s),
                        paper_disc: Metric::Disc.paper(&g.method, s),
                    })
                    .collect(),
            })
            .collect(),
    }
}

/// The comparison in the paper's layout.
pub fn markdown(groups: &[Group]) -> String {
    let mut s = String::from(
        "# Comparison\n\nMean ± standard deviation over the runs (seeds) of each method; a single run shows its value alone; n is the number of runs per setting. AVG is the mean over Env 1–3. Rows marked (paper) are the paper's Tables I–II (SPEC §8).\n\n",
    );
    s += "| method | runs |\n|---|---|\n";
    for g in groups {
        let runs: Vec<&str> = g.members.iter().map(|m| m.label.as_str()).collect();
        let _ = writeln!(s, "| {} | {} |", g.method, runs.join(", "));
    }
    s.push('\n');
    for metric in Metric::ALL {
        let d = metric.digits();
        let _ = writeln!(s, "## {}\n", metric.title());
        let _ = writeln!(s, "| method {PAPER_COLUMNS}");
        let _ = writeln!(s, "|---|---|---|---|---|---|---|---|---|");
        for g in groups {
            let row = paper_layout_row(
                |setting| match g.stat(metric, setting) {
                    Some(st) => (st.text(d), Some(st.mean)),
                    None => ("–".into(), None),
                },
                d,
            );
            let _ = writeln!(s, "| {} (n={}) |{row}", g.method, g.runs_per_setting());
            if let Some(p) = paper_row(metric, &g.method) {
                let _ = writeln!(s, "{p}");
            }
        }
        s.push('\n');
    }
    s
}

fn csv(groups: &[Group]) -> String {
    let mut s = String::from("method,setting,runs");
    for m in Metric::ALL {
        let _ = write!(s, ",{}_mean,{}_std", m.key(), m.key());
    }
    s += ",paper_nav_time_s,paper_disc\n";
    let f = |v: Option<f64>| v.map_or(String::new(), |x| format!("{x}"));
    for g in groups {
        for &setting in &Setting::ALL {
            let n = g.values(Metric::Success, setting).len();
            if n == 0 {
                continue;
            }
            let _ = write!(s, "{},{},{n}", csv_field(&g.method), setting.name());
            for metric in Metric::ALL {
                let st = g.stat(metric, setting);
                let _ = write!(
                    s,
                    ",{},{}",
                    f(st.map(|x| x.mean)),
                    f(st.and_then(|x| x.std))
                );
            }
            let _ = writeln!(
                s,
                ",{},{}",
                f(Metric::NavTime.paper(&g.method, setting)),
                f(Metric::Disc.paper(&g.method, setting))
            );
        }
    }
    s
}

/// The metrics an arm test covers (the paper's five and the timeout rate).
const TESTED: [Metric; 5] = [
    Metric::Success,
    Metric::Collision,
    Metric::Timeout,
    Metric::NavTime,
    Metric::Disc,
];

/// One arm of `--vs`: its sources' groups must be a single method's.
fn arm<'g>(groups: &'g [Group], name: &str) -> anyhow::Result<&'g Group> {
    match groups {
        [g] => Ok(g),
        [] => bail!("arm {name}: no policies in its sources"),
        _ => bail!(
            "arm {name} holds several methods ({}); an arm of --vs is one method's runs",
            groups
                .iter()
                .map(|g| g.method.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        ),
    }
}

#[derive(Serialize)]
struct ArmCell {
    values: Vec<f64>,
    mean: Option<f64>,
    std: Option<f64>,
    ci95: Option<[f64; 2]>,
}

impl ArmCell {
    fn of(values: Vec<f64>) -> Self {
        let st = Stat::of(&values);
        ArmCell {
            mean: st.map(|s| s.mean),
            std: st.and_then(|s| s.std),
            ci95: mean_ci95(&values),
            values,
        }
    }

    fn text(&self, digits: usize) -> String {
        let each: Vec<String> = self
            .values
            .iter()
            .map(|v| format!("{v:.digits$}"))
            .collect();
        let mut s = each.join(" / ");
        if let (Some(m), Some(sd)) = (self.mean, self.std) {
            let _ = write!(s, ": {m:.digits$} ± {sd:.digits$}");
            if let Some([lo, hi]) = self.ci95 {
                let _ = write!(s, " [{lo:.digits$}, {hi:.digits$}]");
            }
        }
        s
    }
}

#[derive(Serialize)]
struct ArmTest {
    setting: String,
    /// Written as its key.
    #[serde(serialize_with = "metric_key")]
    metric: Metric,
    a: ArmCell,
    b: ArmCell,
    /// Null below two runs in either arm or without spread in both.
    welch: Option<Welch>,
}

fn metric_key<S: serde::Serializer>(m: &Metric, s: S) -> Result<S::Ok, S::Error> {
    s.serialize_str(m.key())
}

/// Every setting both arms have, every tested metric.
fn arm_tests(a: &Group, b: &Group) -> Vec<ArmTest> {
    let mut out = Vec::new();
    for &setting in &Setting::ALL {
        if a.values(Metric::Success, setting).is_empty()
            || b.values(Metric::Success, setting).is_empty()
        {
            continue;
        }
        for metric in TESTED {
            let (va, vb) = (a.values(metric, setting), b.values(metric, setting));
            out.push(ArmTest {
                setting: setting.name().into(),
                metric,
                welch: welch(&va, &vb),
                a: ArmCell::of(va),
                b: ArmCell::of(vb),
            });
        }
    }
    out
}

fn pooled(g: &Group, setting: &str) -> (u32, u32) {
    g.members
        .iter()
        .filter_map(|m| m.settings.iter().find(|r| r.setting == setting))
        .fold((0, 0), |(k, n), r| (k + r.successes, n + r.episodes))
}

/// The arms' sources as given on the command line: the reports' own labels name the method,
/// setting and seed, which two arms of one method share.
fn arms_markdown(arms: [(&Group, &[PathBuf]); 2], tests: &[ArmTest]) -> String {
    let mut s = String::from("# Arm A against arm B\n\n");
    for ((g, paths), name) in arms.iter().zip(["A", "B"]) {
        let sources: Vec<String> = paths.iter().map(|p| p.display().to_string()).collect();
        let _ = writeln!(
            s,
            "- {name}: {}, {} runs ({})",
            g.method,
            g.members.len(),
            sources.join(", ")
        );
    }
    s.push('\n');
    let [(a, _), (b, _)] = arms;
    s += "Per run, then mean ± std over runs [95 % t interval]; Welch's t-test of A − B (two-sided p; none below two runs per arm).

";
    s += "| setting | metric | A | B | A − B | t | df | p |
|---|---|---|---|---|---|---|---|
";
    for t in tests {
        let metric = t.metric;
        let d = metric.digits();
        let (mut ta, mut tb) = (t.a.text(d), t.b.text(d));
        if metric == Metric::Success {
            let (ka, na) = pooled(a, &t.setting);
            let (kb, nb) = pooled(b, &t.setting);
            let _ = write!(ta, " (pooled {ka}/{na})");
            let _ = write!(tb, " (pooled {kb}/{nb})");
        }
        let tail = match t.welch {
            Some(w) => format!(
                "{:+.d$} | {:.2} | {:.1} | {:.3}",
                w.difference, w.t, w.df, w.p
            ),
            None => match (t.a.mean, t.b.mean) {
                (Some(x), Some(y)) => format!("{:+.d$} | – | – | –", x - y),
                _ => "– | – | – | –".into(),
            },
        };
        let _ = writeln!(
            s,
            "| {} | {} | {ta} | {tb} | {tail} |",
            t.setting,
            metric.key()
        );
    }
    s
}

/// A comparison written three ways (what `fsrl compare` prints and writes with `--out`).
pub struct Comparison {
    /// The arms' tests (with `vs`) and the methods × settings table.
    pub markdown: String,
    pub csv: String,
    pub json: String,
}

impl Comparison {
    /// Writes `compare.md`, `compare.csv` and `compare.json` into `dir` (created if needed).
    pub fn write_to(&self, dir: &Path) -> anyhow::Result<()> {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
        for (name, text) in [
            ("compare.md", &self.markdown),
            ("compare.csv", &self.csv),
            ("compare.json", &self.json),
        ] {
            let path = dir.join(name);
            std::fs::write(&path, text)
                .with_context(|| format!("cannot write {}", path.display()))?;
        }
        Ok(())
    }
}

/// Compares the runs of `runs` (run directories or `eval.json` files): methods × settings, mean
/// ± std over seeds; with `vs` non-empty, one arm against the other too (Welch's t-test per
/// setting and metric; each arm must hold a single method).
pub fn compare(runs: &[PathBuf], vs: &[PathBuf]) -> anyhow::Result<Comparison> {
    let groups = group(load_sources(runs)?);
    let arms = if vs.is_empty() {
        None
    } else {
        let other = group(load_sources(vs)?);
        let (a, b) = (arm(&groups, "A")?, arm(&other, "B")?);
        let tests = arm_tests(a, b);
        if tests.is_empty() {
            bail!("the two arms have no setting in common");
        }
        Some((arms_markdown([(a, runs), (b, vs)], &tests), tests))
    };
    let markdown = match &arms {
        Some((arms_md, _)) => format!("{arms_md}\n{}", markdown(&groups)),
        None => markdown(&groups),
    };
    let mut json = serde_json::to_value(to_json(&groups))?;
    if let Some((_, tests)) = &arms {
        json["arms"] = serde_json::to_value(tests)?;
    }
    Ok(Comparison {
        markdown,
        csv: csv(&groups),
        json: serde_json::to_string_pretty(&json)?,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::report::EVAL_KIND;

    /// An `eval.json` of one `method` run (`seed`) on env1-invisible: `successes` of 100.
    fn eval_file(dir: &Path, method: &str, seed: u64, successes: u32) -> PathBuf {
        let agg = sim::Aggregate {
            episodes: 100,
            successes,
            collisions: 100 - successes,
            success_time_s: 12.0 * f64::from(successes),
            success_path_m: 10.0 * f64::from(successes),
            steps: 48 * 100,
            ..sim::Aggregate::default()
        };
        let report = EvalReport {
            kind: EVAL_KIND.into(),
            crowd: None,
            test_seed_start: 1000,
            episodes_per_setting: 100,
            subjects: vec![SubjectReport {
                label: format!("{method}-s{seed}"),
                method: method.into(),
                checkpoint: None,
                checkpoint_sha256: None,
                policy_version: 1,
                run_seed: Some(seed),
                planning_top_k: 0,
                planning_breadth: 0,
                shield_s: 0.0,
                progress_tolerance: 0.0,
                trained_setting: Some("env1-invisible".into()),
                settings: vec![SettingReport::new("env1-invisible", &agg)],
            }],
        };
        let path = dir.join(format!("{method}-s{seed}.json"));
        std::fs::write(&path, serde_json::to_string(&report).unwrap()).unwrap();
        path
    }

    #[test]
    fn runs_of_a_method_are_one_row_and_two_arms_are_tested() {
        let tmp = tempfile::tempdir().unwrap();
        let a: Vec<PathBuf> = [(0, 90), (1, 94), (2, 92)]
            .iter()
            .map(|&(s, k)| eval_file(tmp.path(), "fsrl", s, k))
            .collect();
        let b: Vec<PathBuf> = [(0, 70), (1, 74), (2, 72)]
            .iter()
            .map(|&(s, k)| eval_file(tmp.path(), "sarl", s, k))
            .collect();

        let groups = group(load_sources(&[a.clone(), b.clone()].concat()).unwrap());
        assert_eq!(groups.len(), 2);
        assert!(groups.iter().all(|g| g.members.len() == 3));
        let s: Setting = "env1-invisible".parse().unwrap();
        let fsrl = groups.iter().find(|g| g.method == "fsrl").unwrap();
        let st = fsrl.stat(Metric::Success, s).unwrap();
        assert!((st.mean - 0.92).abs() < 1e-12, "{}", st.mean);
        assert!((st.std.unwrap() - 0.02).abs() < 1e-12);

        let c = compare(&a, &b).unwrap();
        let w = welch(&[0.90, 0.94, 0.92], &[0.70, 0.74, 0.72]).unwrap();
        assert!(w.p < 0.001, "{}", w.p);
        let json: serde_json::Value = serde_json::from_str(&c.json).unwrap();
        let arms = json["arms"].as_array().unwrap();
        let success = arms
            .iter()
            .find(|t| t["metric"] == "success" && t["setting"] == "env1-invisible")
            .unwrap();
        assert!(
            (success["welch"]["p"].as_f64().unwrap() - w.p).abs() < 1e-12,
            "{success}"
        );
        assert!(c.markdown.contains("fsrl"), "{}", c.markdown);
        assert!(c.csv.lines().count() > 1);

        // Two methods in one arm: refused, naming the arm.
        let mixed = [a[0].clone(), b[0].clone()];
        let e = format!("{:#}", compare(&mixed, &b).err().unwrap());
        assert!(e.contains('A'), "{e}");
        // Without a second arm: the table alone.
        assert!(compare(&a, &[]).unwrap().json.find("arms").is_none());
    }

    #[test]
    fn a_report_of_another_kind_or_with_impossible_values_is_refused() {
        let tmp = tempfile::tempdir().unwrap();
        let good = eval_file(tmp.path(), "fsrl", 0, 90);
        let text = std::fs::read_to_string(&good).unwrap();
        let other = tmp.path().join("other.json");
        std::fs::write(&other, text.replace(EVAL_KIND, "something-else")).unwrap();
        let e = format!("{:#}", load_sources(&[other]).err().unwrap());
        assert!(e.contains("not an `fsrl eval` report"), "{e}");
        let bad = tmp.path().join("bad.json");
        std::fs::write(&bad, text.replace("\"success\":0.9", "\"success\":1.9")).unwrap();
        assert!(load_sources(&[bad]).is_err());
    }
}
