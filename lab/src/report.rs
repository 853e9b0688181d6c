//! Evaluation reports: the paper's metrics per setting with their uncertainty, as JSON, CSV and
//! Markdown in the paper's table layout (Tables I and II: invisible Env 1–3 and average, then
//! visible), with the paper's numbers (SPEC §8) beside ours.
//!
//! Uncertainty: success, collision and timeout rates carry a 95% Wilson score interval; the
//! navigation time (mean over successful episodes) a 95% Student-t interval. Field names are
//! stable and plain (`success`, `success_ci95`, `nav_time_s`, ...) so other tools can read them.

use std::fmt::Write as _;
use std::path::Path;

use anyhow::Context;
use serde::{Deserialize, Serialize};
use sim::{Aggregate, Setting};
use statrs::distribution::{ContinuousCDF, StudentsT};

/// z for a two-sided 95% interval.
const Z95: f64 = 1.959_963_984_540_054;

/// The 95% Wilson score interval of `k` successes in `n` trials ([0, 1] when `n` = 0).
pub fn wilson(k: u32, n: u32) -> [f64; 2] {
    if n == 0 {
        return [0.0, 1.0];
    }
    let (k, n) = (k as f64, n as f64);
    let p = k / n;
    let z2 = Z95 * Z95;
    let denom = 1.0 + z2 / n;
    let centre = (p + z2 / (2.0 * n)) / denom;
    let half = Z95 / denom * (p * (1.0 - p) / n + z2 / (4.0 * n * n)).sqrt();
    // At k = 0 (k = n) the lower (upper) bound is exactly 0 (1); rounding would leave ±1e-18.
    let lo = if k == 0.0 {
        0.0
    } else {
        (centre - half).max(0.0)
    };
    let hi = if k == n {
        1.0
    } else {
        (centre + half).min(1.0)
    };
    [lo, hi]
}

/// The 0.975 quantile of Student's t with `df` degrees of freedom (infinite at 0).
pub fn t975(df: u32) -> f64 {
    students_t(f64::from(df)).map_or(f64::INFINITY, |t| t.inverse_cdf(0.975))
}

/// Student's t with `df` degrees of freedom (`None` unless `df` > 0 and finite).
fn students_t(df: f64) -> Option<StudentsT> {
    StudentsT::new(0.0, 1.0, df).ok().filter(|_| df.is_finite())
}

/// Welch's unequal-variance t-test of the means of two samples.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Welch {
    /// mean(a) − mean(b).
    pub difference: f64,
    pub t: f64,
    /// Welch–Satterthwaite degrees of freedom.
    pub df: f64,
    /// Two-sided p-value.
    pub p: f64,
}

/// Welch's t-test of mean(a) = mean(b); `None` below two values in either sample or when
/// neither varies (then no spread estimates the noise).
pub fn welch(a: &[f64], b: &[f64]) -> Option<Welch> {
    let (ma, sa) = mean_std(a)?;
    let (mb, sb) = mean_std(b)?;
    let (va, vb) = (sa?.powi(2) / a.len() as f64, sb?.powi(2) / b.len() as f64);
    let se2 = va + vb;
    if se2.is_nan() || se2 <= 0.0 {
        return None;
    }
    let difference = ma - mb;
    let t = difference / se2.sqrt();
    let df = se2.powi(2) / (va.powi(2) / (a.len() - 1) as f64 + vb.powi(2) / (b.len() - 1) as f64);
    let p = 2.0 * students_t(df)?.sf(t.abs());
    Some(Welch {
        difference,
        t,
        df,
        p: p.min(1.0),
    })
}

/// `xs` as a table cell: "mean ± std" with `digits` decimals, the mean alone for one value,
/// "–" for none.
pub fn mean_std_cell(xs: &[f64], digits: usize) -> String {
    match mean_std(xs) {
        Some((m, Some(sd))) => format!("{m:.digits$} ± {sd:.digits$}"),
        Some((m, None)) => format!("{m:.digits$}"),
        None => "–".into(),
    }
}

/// Mean, sample standard deviation (`None` below two values) of `xs`.
pub fn mean_std(xs: &[f64]) -> Option<(f64, Option<f64>)> {
    if xs.is_empty() {
        return None;
    }
    let n = xs.len() as f64;
    let mean = xs.iter().sum::<f64>() / n;
    let std = (xs.len() > 1)
        .then(|| (xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt());
    Some((mean, std))
}

/// The 95% t interval of the mean of `xs` (`None` below two values).
pub fn mean_ci95(xs: &[f64]) -> Option<[f64; 2]> {
    let (mean, std) = mean_std(xs)?;
    let half = t975(xs.len() as u32 - 1) * std? / (xs.len() as f64).sqrt();
    Some([mean - half, mean + half])
}

/// Per-episode samples of one setting, for the intervals an aggregate cannot give.
#[derive(Debug, Clone, Default)]
pub struct Samples {
    /// Navigation times of the successful episodes.
    pub nav_times_s: Vec<f64>,
    /// Path lengths of the successful episodes.
    pub path_lengths_m: Vec<f64>,
    /// Returns of all episodes.
    pub returns: Vec<f64>,
}

/// One setting's metrics, with field names other tools can read.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SettingReport {
    pub setting: String,
    pub episodes: u32,
    #[serde(default)]
    pub successes: u32,
    #[serde(default)]
    pub collisions: u32,
    #[serde(default)]
    pub timeouts: u32,
    pub success: f64,
    /// 95% Wilson interval.
    #[serde(default)]
    pub success_ci95: Option<[f64; 2]>,
    pub collision: f64,
    #[serde(default)]
    pub collision_ci95: Option<[f64; 2]>,
    pub timeout: f64,
    #[serde(default)]
    pub timeout_ci95: Option<[f64; 2]>,
    /// Mean over successful episodes; null without a success.
    pub nav_time_s: Option<f64>,
    /// 95% t interval of the mean nav time; null without per-episode samples or below two
    /// successes.
    #[serde(default)]
    pub nav_time_ci95_s: Option<[f64; 2]>,
    #[serde(default)]
    pub nav_time_std_s: Option<f64>,
    /// Disc.: danger steps / all steps.
    pub disc: f64,
    #[serde(default)]
    pub danger_steps: u64,
    #[serde(default)]
    pub steps: u64,
    /// Mean over successful episodes.
    pub path_length_m: Option<f64>,
    #[serde(default)]
    pub path_length_std_m: Option<f64>,
    /// Smoothness: mean |Δθ| per step.
    pub mean_abs_rotation_rad: f64,
    pub mean_return: f64,
    #[serde(default)]
    pub return_std: Option<f64>,
    /// Wall and people collisions and frozen robots apart: only in the walled settings (issue
    /// 53), absent from every report of the paper's six (whose JSON stays as it was).
    #[serde(flatten, skip_serializing_if = "Option::is_none")]
    pub walls: Option<WallReport>,
}

/// How the collisions of a walled setting split (walls, people) and how many robots froze,
/// counts and rates with their 95% Wilson intervals. Wall and people collisions add up to
/// [`SettingReport::collisions`]; frozen robots are among [`SettingReport::timeouts`] (a timed-out
/// robot that moved less than `sim::FROZEN_DISTANCE_M` over its last `sim::FROZEN_WINDOW_S`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct WallReport {
    pub wall_collisions: u32,
    pub people_collisions: u32,
    pub frozen_robots: u32,
    /// Wall collisions / episodes.
    pub wall_collision: f64,
    pub wall_collision_ci95: [f64; 2],
    /// People collisions / episodes.
    pub people_collision: f64,
    pub people_collision_ci95: [f64; 2],
    /// Frozen robots / episodes.
    pub frozen_robot: f64,
    pub frozen_robot_ci95: [f64; 2],
}

impl WallReport {
    pub fn new(a: &Aggregate) -> Self {
        let people = a.collisions.saturating_sub(a.wall_collisions);
        Self {
            wall_collisions: a.wall_collisions,
            people_collisions: people,
            frozen_robots: a.frozen,
            wall_collision: a.wall_collision_rate(),
            wall_collision_ci95: wilson(a.wall_collisions, a.episodes),
            people_collision: a.people_collision_rate(),
            people_collision_ci95: wilson(people, a.episodes),
            frozen_robot: a.frozen_rate(),
            frozen_robot_ci95: wilson(a.frozen, a.episodes),
        }
    }

    /// The counts add up to the report's (wall + people = collisions, frozen ≤ timeouts) and
    /// give the rates.
    fn check(&self, r: &SettingReport) -> Result<(), String> {
        let s = &r.setting;
        if u64::from(self.wall_collisions) + u64::from(self.people_collisions)
            != u64::from(r.collisions)
            || self.frozen_robots > r.timeouts
        {
            return Err(format!(
                "{s}: {} wall + {} people collisions, {} frozen robots do not split {} collisions and {} timeouts",
                self.wall_collisions,
                self.people_collisions,
                self.frozen_robots,
                r.collisions,
                r.timeouts
            ));
        }
        let n = f64::from(r.episodes);
        for (name, k, rate) in [
            ("wall_collision", self.wall_collisions, self.wall_collision),
            (
                "people_collision",
                self.people_collisions,
                self.people_collision,
            ),
            ("frozen_robot", self.frozen_robots, self.frozen_robot),
        ] {
            // NaN fails too.
            let matches = (f64::from(k) / n - rate).abs() <= 1e-9;
            if !matches {
                return Err(format!("{s}: {name} {rate} is not {k} of {n} episodes"));
            }
        }
        Ok(())
    }
}

impl SettingReport {
    /// What a report read from a file must hold before anything averages it: a known setting,
    /// episodes, rates in [0, 1] that add up to one (and match the counts where the counts are
    /// recorded), Disc. a fraction, a positive Nav. Time, finite values. A report edited by
    /// hand or cut by a crash is refused with the field that is wrong, not averaged in.
    pub fn check(&self) -> Result<(), String> {
        let s = &self.setting;
        s.parse::<Setting>()
            .map_err(|e| format!("setting {s:?}: {e}"))?;
        if self.episodes == 0 {
            return Err(format!("{s}: no episodes"));
        }
        for (name, v) in [
            ("success", self.success),
            ("collision", self.collision),
            ("timeout", self.timeout),
            ("disc", self.disc),
        ] {
            if !(0.0..=1.0).contains(&v) {
                return Err(format!("{s}: {name} {v} is not a fraction in [0, 1]"));
            }
        }
        let sum = self.success + self.collision + self.timeout;
        if (sum - 1.0).abs() > 1e-6 {
            return Err(format!(
                "{s}: success + collision + timeout = {sum}, not 1 (every episode ends one way)"
            ));
        }
        let counted =
            u64::from(self.successes) + u64::from(self.collisions) + u64::from(self.timeouts);
        if counted > 0 {
            let n = f64::from(self.episodes);
            if counted != u64::from(self.episodes)
                || (f64::from(self.successes) / n - self.success).abs() > 1e-9
            {
                return Err(format!(
                    "{s}: counts {}/{}/{} of {} episodes do not give the rates {}/{}/{}",
                    self.successes,
                    self.collisions,
                    self.timeouts,
                    self.episodes,
                    self.success,
                    self.collision,
                    self.timeout
                ));
            }
        }
        match (&self.walls, self.parsed_setting()) {
            (Some(w), Some(setting)) if !setting.is_paper() => w.check(self)?,
            (Some(_), _) => return Err(format!("{s}: wall collisions in a setting without walls")),
            (None, _) => {}
        }
        if self.danger_steps > self.steps {
            return Err(format!(
                "{s}: {} danger steps of {} steps",
                self.danger_steps, self.steps
            ));
        }
        for (name, v) in [
            ("nav_time_s", self.nav_time_s),
            ("path_length_m", self.path_length_m),
        ] {
            if let Some(v) = v.filter(|v| !(v.is_finite() && *v > 0.0)) {
                return Err(format!("{s}: {name} {v} is not a positive time or length"));
            }
        }
        let rotation_ok =
            self.mean_abs_rotation_rad.is_finite() && self.mean_abs_rotation_rad >= 0.0;
        if !(rotation_ok && self.mean_return.is_finite()) {
            return Err(format!(
                "{s}: mean_abs_rotation_rad {} / mean_return {} not finite",
                self.mean_abs_rotation_rad, self.mean_return
            ));
        }
        Ok(())
    }

    /// From an aggregate alone: rates with Wilson intervals, no nav-time interval.
    pub fn new(setting: &str, a: &Aggregate) -> Self {
        Self {
            setting: setting.to_string(),
            episodes: a.episodes,
            successes: a.successes,
            collisions: a.collisions,
            timeouts: a.timeouts,
            success: a.success_rate(),
            success_ci95: Some(wilson(a.successes, a.episodes)),
            collision: a.collision_rate(),
            collision_ci95: Some(wilson(a.collisions, a.episodes)),
            timeout: a.timeout_rate(),
            timeout_ci95: Some(wilson(a.timeouts, a.episodes)),
            nav_time_s: a.nav_time_s(),
            nav_time_ci95_s: None,
            nav_time_std_s: None,
            disc: a.discomfort(),
            danger_steps: a.danger_steps,
            steps: a.steps,
            path_length_m: a.path_length_m(),
            path_length_std_m: None,
            mean_abs_rotation_rad: a.mean_abs_rotation_rad(),
            mean_return: a.mean_return(),
            return_std: None,
            walls: setting
                .parse::<Setting>()
                .is_ok_and(|s| !s.is_paper())
                .then(|| WallReport::new(a)),
        }
    }

    /// From an aggregate and its per-episode samples: every interval.
    pub fn with_samples(setting: &str, a: &Aggregate, s: &Samples) -> Self {
        let mut r = Self::new(setting, a);
        r.nav_time_ci95_s = mean_ci95(&s.nav_times_s);
        r.nav_time_std_s = mean_std(&s.nav_times_s).and_then(|m| m.1);
        r.path_length_std_m = mean_std(&s.path_lengths_m).and_then(|m| m.1);
        r.return_std = mean_std(&s.returns).and_then(|m| m.1);
        r
    }

    /// The setting, when the name is a known one.
    pub fn parsed_setting(&self) -> Option<Setting> {
        self.setting.parse().ok()
    }
}

/// The report `fsrl train` writes after training (one method, the trained setting).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Report {
    pub method: String,
    pub policy_version: u64,
    pub test_seed_start: u64,
    pub settings: Vec<SettingReport>,
}

fn opt(v: Option<f64>, digits: usize) -> String {
    v.map_or_else(|| "–".to_string(), |x| format!("{x:.digits$}"))
}

fn interval(v: f64, ci: Option<[f64; 2]>, digits: usize) -> String {
    match ci {
        Some([lo, hi]) => format!("{v:.digits$} [{lo:.digits$}, {hi:.digits$}]"),
        None => format!("{v:.digits$}"),
    }
}

fn opt_interval(v: Option<f64>, ci: Option<[f64; 2]>, digits: usize) -> String {
    v.map_or_else(|| "–".to_string(), |v| interval(v, ci, digits))
}

/// The three cells of a walled setting's split (wall coll., people coll., frozen), "–" in a
/// setting without walls.
fn wall_cells(r: &SettingReport, digits: usize) -> String {
    match &r.walls {
        Some(w) => format!(
            " {} | {} | {} |",
            interval(w.wall_collision, Some(w.wall_collision_ci95), digits),
            interval(w.people_collision, Some(w.people_collision_ci95), digits),
            interval(w.frozen_robot, Some(w.frozen_robot_ci95), digits),
        ),
        None => " – | – | – |".into(),
    }
}

/// Headers of [`wall_cells`].
const WALL_COLUMNS: &str = " Wall coll. | People coll. | Frozen |";

/// A per-setting table of every metric with its interval; with a walled setting among them, the
/// wall collision, people collision and frozen-robot rates too.
fn detail_table(settings: &[SettingReport]) -> String {
    let walled = settings.iter().any(|r| r.walls.is_some());
    let mut s = String::from(
        "| setting | episodes | Succ. | Coll. | Timeout | Nav. Time (s) | Disc. | Path (m) | mean abs dθ (rad/step) | return |",
    );
    if walled {
        s += WALL_COLUMNS;
    }
    s += "\n|---|---|---|---|---|---|---|---|---|---|";
    if walled {
        s += "---|---|---|";
    }
    s.push('\n');
    for r in settings {
        let _ = write!(
            s,
            "| {} | {} | {} | {} | {} | {} | {:.3} | {} | {:.4} | {:.3} |",
            r.setting,
            r.episodes,
            interval(r.success, r.success_ci95, 3),
            interval(r.collision, r.collision_ci95, 3),
            interval(r.timeout, r.timeout_ci95, 3),
            opt_interval(r.nav_time_s, r.nav_time_ci95_s, 2),
            r.disc,
            opt(r.path_length_m, 2),
            r.mean_abs_rotation_rad,
            r.mean_return,
        );
        if walled {
            s += &wall_cells(r, 3);
        }
        s.push('\n');
    }
    s
}

impl Report {
    /// Every metric per setting, rates with 95% Wilson intervals.
    pub fn markdown(&self) -> String {
        format!(
            "Method `{}`, policy version {}, test seeds from {}. Brackets: 95% intervals (Wilson for rates, t for Nav. Time).\n\n{}",
            self.method,
            self.policy_version,
            self.test_seed_start,
            detail_table(&self.settings)
        )
    }
}

// ---------------------------------------------------------------------------------------------
// The paper's numbers (SPEC §8).

/// Paper table rows, in [`Setting::ALL`] order (invisible Env 1–3, visible Env 1–3).
const PAPER_NAV_TIME: [(&str, [f64; 6]); 4] = [
    ("orca", [12.49, 11.98, 12.04, 11.99, 10.97, 10.74]),
    ("lstm-rl", [15.52, 14.12, 12.81, 11.01, 10.96, 12.32]),
    ("sarl", [12.25, 11.39, 11.15, 9.85, 10.33, 10.01]),
    ("fsrl", [10.90, 10.92, 11.69, 11.08, 10.32, 11.60]),
];
const PAPER_NAV_TIME_AVG: [(&str, [f64; 2]); 4] = [
    ("orca", [12.14, 11.23]),
    ("lstm-rl", [14.15, 11.29]),
    ("sarl", [11.60, 10.06]),
    ("fsrl", [11.04, 11.00]),
];
const PAPER_DISC: [(&str, [f64; 6]); 4] = [
    ("orca", [0.39, 0.38, 0.43, 0.41, 0.41, 0.45]),
    ("lstm-rl", [0.07, 0.28, 0.16, 0.11, 0.35, 0.39]),
    ("sarl", [0.01, 0.06, 0.06, 0.09, 0.11, 0.10]),
    ("fsrl", [0.01, 0.07, 0.04, 0.06, 0.08, 0.07]),
];
const PAPER_DISC_AVG: [(&str, [f64; 2]); 4] = [
    ("orca", [0.40, 0.42]),
    ("lstm-rl", [0.17, 0.20]),
    ("sarl", [0.04, 0.10]),
    ("fsrl", [0.04, 0.07]),
];

/// The metrics of the paper's tables (and ours beside them).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Metric {
    Success,
    Collision,
    Timeout,
    NavTime,
    Disc,
    PathLength,
    Smoothness,
    Return,
}

impl Metric {
    pub const ALL: [Metric; 8] = [
        Metric::Success,
        Metric::Collision,
        Metric::Timeout,
        Metric::NavTime,
        Metric::Disc,
        Metric::PathLength,
        Metric::Smoothness,
        Metric::Return,
    ];

    /// The field name in reports (JSON keys, CSV columns).
    pub fn key(self) -> &'static str {
        match self {
            Metric::Success => "success",
            Metric::Collision => "collision",
            Metric::Timeout => "timeout",
            Metric::NavTime => "nav_time_s",
            Metric::Disc => "disc",
            Metric::PathLength => "path_length_m",
            Metric::Smoothness => "mean_abs_rotation_rad",
            Metric::Return => "mean_return",
        }
    }

    pub fn title(self) -> &'static str {
        match self {
            Metric::Success => "Succ. (success rate)",
            Metric::Collision => "Coll. (collision rate)",
            Metric::Timeout => "Timeout (timeout rate)",
            Metric::NavTime => "Nav. Time (s, mean over successful episodes; paper Table I)",
            Metric::Disc => "Disc. (danger steps / all steps; paper Table II, whose header says % but whose numbers are these fractions)",
            Metric::PathLength => "Path length (m, mean over successful episodes)",
            Metric::Smoothness => "Smoothness (mean |Δθ| per step, rad)",
            Metric::Return => "Mean return (the method's own reward)",
        }
    }

    pub fn digits(self) -> usize {
        match self {
            Metric::Success | Metric::Collision | Metric::Timeout | Metric::Disc => 3,
            Metric::NavTime | Metric::PathLength => 2,
            Metric::Smoothness => 4,
            Metric::Return => 3,
        }
    }

    /// Our value and its interval on one setting.
    pub fn of(self, r: &SettingReport) -> Option<(f64, Option<[f64; 2]>)> {
        match self {
            Metric::Success => Some((r.success, r.success_ci95)),
            Metric::Collision => Some((r.collision, r.collision_ci95)),
            Metric::Timeout => Some((r.timeout, r.timeout_ci95)),
            Metric::NavTime => r.nav_time_s.map(|v| (v, r.nav_time_ci95_s)),
            Metric::Disc => Some((r.disc, None)),
            Metric::PathLength => r.path_length_m.map(|v| (v, None)),
            Metric::Smoothness => Some((r.mean_abs_rotation_rad, None)),
            Metric::Return => Some((r.mean_return, None)),
        }
    }

    /// The paper's value for `method` on `setting`, where the paper has one (never in a walled
    /// setting).
    pub fn paper(self, method: &str, setting: Setting) -> Option<f64> {
        if !setting.is_paper() {
            return None;
        }
        let table = match self {
            Metric::NavTime => &PAPER_NAV_TIME,
            Metric::Disc => &PAPER_DISC,
            _ => return None,
        };
        table
            .iter()
            .find(|(m, _)| *m == method)
            .map(|(_, v)| v[setting.index()])
    }

    /// The paper's average over Env 1–3 of one visibility.
    pub fn paper_avg(self, method: &str, visible: bool) -> Option<f64> {
        let table = match self {
            Metric::NavTime => &PAPER_NAV_TIME_AVG,
            Metric::Disc => &PAPER_DISC_AVG,
            _ => return None,
        };
        table
            .iter()
            .find(|(m, _)| *m == method)
            .map(|(_, v)| v[visible as usize])
    }

    pub fn has_paper(self) -> bool {
        matches!(self, Metric::NavTime | Metric::Disc)
    }
}

/// The paper's name of a method.
pub fn paper_name(method: &str) -> &str {
    match method {
        "orca" => "ORCA",
        "lstm-rl" => "LSTM-RL",
        "sarl" => "SARL",
        "fsrl" => "FSRL",
        m => m,
    }
}

/// Column headers of the paper's layout.
pub const PAPER_COLUMNS: &str = "| inv. Env 1 | inv. Env 2 | inv. Env 3 | inv. AVG | vis. Env 1 | vis. Env 2 | vis. Env 3 | vis. AVG |";

/// One row of the paper layout: the six settings' cells with the two averages inserted.
/// `cell(setting)` gives (text, value for the average).
pub fn paper_layout_row(cell: impl Fn(Setting) -> (String, Option<f64>), digits: usize) -> String {
    let mut out = String::new();
    for visible in [false, true] {
        let mut values = Vec::new();
        for s in Setting::ALL.iter().filter(|s| s.robot_visible == visible) {
            let (text, v) = cell(*s);
            values.extend(v);
            let _ = write!(out, " {text} |");
        }
        // The average exists only when all three environments have a value.
        let avg = (values.len() == 3).then(|| values.iter().sum::<f64>() / 3.0);
        let _ = write!(out, " {} |", opt(avg, digits));
    }
    out
}

/// The paper's row for `metric` and `method`, when it has one.
pub fn paper_row(metric: Metric, method: &str) -> Option<String> {
    Metric::paper(metric, method, Setting::ALL[0])?;
    let d = metric.digits().min(2);
    let mut out = format!("| {} (paper) |", paper_name(method));
    for visible in [false, true] {
        for s in Setting::ALL.iter().filter(|s| s.robot_visible == visible) {
            let _ = write!(out, " {} |", opt(metric.paper(method, *s), d));
        }
        let _ = write!(out, " {} |", opt(metric.paper_avg(method, visible), d));
    }
    Some(out)
}

// ---------------------------------------------------------------------------------------------
// `fsrl eval` reports.

/// One evaluated policy.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SubjectReport {
    /// A short name for tables and legends (run directory name, checkpoint file, or `orca`).
    pub label: String,
    /// orca, lstm-rl, sarl, fsrl, sarl+foresight, sarl+efficiency
    pub method: String,
    /// The checkpoint or model file evaluated (null for ORCA).
    pub checkpoint: Option<String>,
    /// SHA-256 (64 hex digits) of that file's bytes when it was evaluated: which exact weights
    /// the report is of (absent for ORCA and in reports of older fsrl versions; the
    /// `checkpoint_crc32` those wrote is ignored, see [`crate::cmd_eval::file_sha256`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub checkpoint_sha256: Option<String>,
    pub policy_version: u64,
    /// The training run's seed and setting, when known.
    pub run_seed: Option<u64>,
    pub trained_setting: Option<String>,
    /// Depth-2 planning over this many best first steps decided the episodes (absent: 0, the
    /// paper's one-step lookahead).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub planning_top_k: usize,
    /// The second steps tried after each planned first step (absent: 0, every action).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub planning_breadth: usize,
    /// The people shield's horizon the decisions had (absent: 0, off; `train.shield_s`).
    #[serde(default, skip_serializing_if = "is_zero_f64")]
    pub shield_s: f64,
    /// The progress tie-break's tolerance the decisions had (absent: 0, off;
    /// `train.progress_tolerance`).
    #[serde(default, skip_serializing_if = "is_zero_f64")]
    pub progress_tolerance: f64,
    pub settings: Vec<SettingReport>,
}

fn is_zero(n: &usize) -> bool {
    *n == 0
}

fn is_zero_f64(v: &f64) -> bool {
    *v == 0.0
}

impl SubjectReport {
    pub fn setting(&self, s: Setting) -> Option<&SettingReport> {
        self.settings.iter().find(|r| r.setting == s.name())
    }
}

/// What `fsrl eval` writes (`eval.json`).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct EvalReport {
    /// Always "fsrl eval": lets readers tell this file from other JSON.
    pub kind: String,
    pub test_seed_start: u64,
    pub episodes_per_setting: u32,
    /// The crowd every subject met when it was not the one each was trained with
    /// (`fsrl eval --people / --crowd`, e.g. "20 moving people, social-force people").
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub crowd: Option<String>,
    pub subjects: Vec<SubjectReport>,
}

pub const EVAL_KIND: &str = "fsrl eval";

impl EvalReport {
    /// The paper's layout, one table per metric, our rows with the paper's beside them; then
    /// every subject's per-setting details.
    pub fn markdown(&self) -> String {
        // The paper's layout only when a paper setting was evaluated (a walled evaluation alone
        // has no cell in it).
        let paper_settings = self
            .subjects
            .iter()
            .flat_map(|subj| &subj.settings)
            .any(|r| r.parsed_setting().is_some_and(|s| s.is_paper()));
        let mut s = format!(
            "# Evaluation\n\n{} test episodes per setting, seeds {}..{}. Rates carry 95% Wilson intervals and Nav. Time a 95% t interval, in brackets{}\n\n",
            self.episodes_per_setting,
            self.test_seed_start,
            self.test_seed_start + self.episodes_per_setting as u64 - 1,
            if paper_settings {
                "; AVG is the mean over Env 1–3. Rows marked (paper) are the paper's Tables I–II (SPEC §8); the paper has no table of rates (only its Fig. 5)."
            } else {
                "."
            }
        );
        if let Some(crowd) = &self.crowd {
            let _ = writeln!(
                s,
                "Crowd: {crowd}, not the crowd the policies were trained with.\n"
            );
        }
        for metric in Metric::ALL.into_iter().filter(|_| paper_settings) {
            let d = metric.digits();
            let _ = writeln!(s, "## {}\n", metric.title());
            let _ = writeln!(s, "| method {PAPER_COLUMNS}");
            let _ = writeln!(s, "|---|---|---|---|---|---|---|---|---|");
            let mut paper_done = Vec::new();
            for subj in &self.subjects {
                let row = paper_layout_row(
                    |setting| match subj.setting(setting).and_then(|r| metric.of(r)) {
                        Some((v, ci)) => (interval(v, ci, d), Some(v)),
                        None => ("–".into(), None),
                    },
                    d,
                );
                let _ = writeln!(s, "| {} |{row}", subj.label);
                if metric.has_paper() && !paper_done.contains(&subj.method) {
                    if let Some(p) = paper_row(metric, &subj.method) {
                        let _ = writeln!(s, "{p}");
                    }
                    paper_done.push(subj.method.clone());
                }
            }
            s.push('\n');
        }
        s += &self.walled_markdown();
        s += "## Details per policy\n\n";
        for subj in &self.subjects {
            let _ = writeln!(
                s,
                "### {}\n\nMethod `{}`, policy version {}{}{}.\n\n{}",
                subj.label,
                subj.method,
                subj.policy_version,
                subj.checkpoint
                    .as_ref()
                    .map_or(String::new(), |c| format!(", checkpoint `{c}`")),
                subj.trained_setting
                    .as_ref()
                    .map_or(String::new(), |t| format!(
                        ", trained on {t} (run seed {})",
                        subj.run_seed.unwrap_or(0)
                    )),
                detail_table(&subj.settings)
            );
        }
        s
    }

    /// The walled settings' table (issue 53): one row per (policy, walled setting), collisions
    /// split into walls and people and the frozen robots beside success, Nav. Time and Disc.;
    /// empty without a walled setting.
    pub fn walled_markdown(&self) -> String {
        let rows: Vec<(&SubjectReport, &SettingReport, &WallReport)> = self
            .subjects
            .iter()
            .flat_map(|subj| {
                subj.settings
                    .iter()
                    .filter_map(move |r| r.walls.as_ref().map(|w| (subj, r, w)))
            })
            .collect();
        if rows.is_empty() {
            return String::new();
        }
        let mut s = format!(
            "## Walled settings\n\nCollisions split into walls and people (Wall coll. + People coll. = Coll.); Frozen: timed-out episodes whose robot moved less than {} m over its last {} s (among Timeout). Brackets: 95% intervals.\n\n| method | setting | Succ. | Coll. | Wall coll. | People coll. | Timeout | Frozen | Nav. Time (s) | Disc. |\n|---|---|---|---|---|---|---|---|---|---|\n",
            sim::episode::FROZEN_DISTANCE_M,
            sim::episode::FROZEN_WINDOW_S
        );
        for (subj, r, w) in rows {
            let _ = writeln!(
                s,
                "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {:.3} |",
                subj.label,
                r.setting,
                interval(r.success, r.success_ci95, 3),
                interval(r.collision, r.collision_ci95, 3),
                interval(w.wall_collision, Some(w.wall_collision_ci95), 3),
                interval(w.people_collision, Some(w.people_collision_ci95), 3),
                interval(r.timeout, r.timeout_ci95, 3),
                interval(w.frozen_robot, Some(w.frozen_robot_ci95), 3),
                opt_interval(r.nav_time_s, r.nav_time_ci95_s, 2),
                r.disc,
            );
        }
        s.push('\n');
        s
    }

    /// One row per (policy, setting), every metric and interval bound in its own column; with a
    /// walled setting in the report, its wall/people collision and frozen-robot counts and rates
    /// in columns after them (empty for a setting without walls).
    pub fn csv(&self) -> String {
        let walled = self
            .subjects
            .iter()
            .flat_map(|subj| &subj.settings)
            .any(|r| r.walls.is_some());
        let mut s = String::from(
            "label,method,checkpoint,policy_version,run_seed,trained_setting,setting,episodes,successes,collisions,timeouts,success,success_lo,success_hi,collision,collision_lo,collision_hi,timeout,timeout_lo,timeout_hi,nav_time_s,nav_time_lo_s,nav_time_hi_s,nav_time_std_s,disc,danger_steps,steps,path_length_m,path_length_std_m,mean_abs_rotation_rad,mean_return,return_std,paper_nav_time_s,paper_disc",
        );
        if walled {
            s += ",wall_collisions,people_collisions,frozen_robots,wall_collision,wall_collision_lo,wall_collision_hi,people_collision,people_collision_lo,people_collision_hi,frozen_robot,frozen_robot_lo,frozen_robot_hi";
        }
        s.push('\n');
        let f = |v: Option<f64>| v.map_or(String::new(), |x| format!("{x}"));
        let lo = |c: Option<[f64; 2]>| f(c.map(|c| c[0]));
        let hi = |c: Option<[f64; 2]>| f(c.map(|c| c[1]));
        for subj in &self.subjects {
            for r in &subj.settings {
                let setting = r.parsed_setting();
                let paper = |m: Metric| f(setting.and_then(|st| m.paper(&subj.method, st)));
                let fields = [
                    csv_field(&subj.label),
                    csv_field(&subj.method),
                    csv_field(subj.checkpoint.as_deref().unwrap_or("")),
                    subj.policy_version.to_string(),
                    subj.run_seed.map_or(String::new(), |v| v.to_string()),
                    csv_field(subj.trained_setting.as_deref().unwrap_or("")),
                    csv_field(&r.setting),
                    r.episodes.to_string(),
                    r.successes.to_string(),
                    r.collisions.to_string(),
                    r.timeouts.to_string(),
                    r.success.to_string(),
                    lo(r.success_ci95),
                    hi(r.success_ci95),
                    r.collision.to_string(),
                    lo(r.collision_ci95),
                    hi(r.collision_ci95),
                    r.timeout.to_string(),
                    lo(r.timeout_ci95),
                    hi(r.timeout_ci95),
                    f(r.nav_time_s),
                    lo(r.nav_time_ci95_s),
                    hi(r.nav_time_ci95_s),
                    f(r.nav_time_std_s),
                    r.disc.to_string(),
                    r.danger_steps.to_string(),
                    r.steps.to_string(),
                    f(r.path_length_m),
                    f(r.path_length_std_m),
                    r.mean_abs_rotation_rad.to_string(),
                    r.mean_return.to_string(),
                    f(r.return_std),
                    paper(Metric::NavTime),
                    paper(Metric::Disc),
                ];
                s += &fields.join(",");
                if walled {
                    let w = r.walls.as_ref();
                    let ci = |c: Option<[f64; 2]>| [lo(c), hi(c)];
                    let mut extra = vec![
                        f(w.map(|w| f64::from(w.wall_collisions))),
                        f(w.map(|w| f64::from(w.people_collisions))),
                        f(w.map(|w| f64::from(w.frozen_robots))),
                        f(w.map(|w| w.wall_collision)),
                    ];
                    extra.extend(ci(w.map(|w| w.wall_collision_ci95)));
                    extra.push(f(w.map(|w| w.people_collision)));
                    extra.extend(ci(w.map(|w| w.people_collision_ci95)));
                    extra.push(f(w.map(|w| w.frozen_robot)));
                    extra.extend(ci(w.map(|w| w.frozen_robot_ci95)));
                    s.push(',');
                    s += &extra.join(",");
                }
                s.push('\n');
            }
        }
        s
    }

    /// Writes eval.md, eval.csv and eval.json into `dir`.
    pub fn write(&self, dir: &Path) -> anyhow::Result<()> {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
        for (name, text) in [
            ("eval.md", self.markdown()),
            ("eval.csv", self.csv()),
            ("eval.json", serde_json::to_string_pretty(self)?),
        ] {
            let path = dir.join(name);
            std::fs::write(&path, text)
                .with_context(|| format!("cannot write {}", path.display()))?;
        }
        Ok(())
    }
}

/// Quotes a CSV field when it needs it (RFC 4180).
pub fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wilson_matches_known_values() {
        // 8 of 10: the textbook interval is [0.490, 0.943].
        let [lo, hi] = wilson(8, 10);
        assert!(
            (lo - 0.4902).abs() < 1e-3 && (hi - 0.9433).abs() < 1e-3,
            "{lo} {hi}"
        );
        assert_eq!(wilson(0, 0), [0.0, 1.0]);
        let [lo, hi] = wilson(0, 500);
        assert_eq!(lo, 0.0);
        assert!(hi > 0.0 && hi < 0.01);
        let [lo, hi] = wilson(500, 500);
        assert!(lo > 0.99 && (hi - 1.0).abs() < 1e-12);
    }

    #[test]
    fn t_interval() {
        assert!((t975(10) - 2.228).abs() < 1e-3);
        assert!((t975(60) - 2.000).abs() < 1e-3);
        assert!((t975(1000) - 1.962).abs() < 1e-3);
        let ci = mean_ci95(&[10.0, 12.0]).unwrap();
        // mean 11, std √2, half = t(0.975, 1)·√2/√2 (SciPy: t.ppf(0.975, 1) = 12.706205).
        assert!((ci[0] - (11.0 - 12.706205)).abs() < 1e-5, "{ci:?}");
        assert!(mean_ci95(&[3.0]).is_none());
        assert_eq!(t975(0), f64::INFINITY);
        // SciPy: t.ppf(0.975, 2) = 4.302653.
        assert!((t975(2) - 4.302653).abs() < 1e-5);
    }

    #[test]
    fn welch_matches_known_values() {
        // SciPy 1.x: ttest_ind([0.978, 0.982, 0.984], [0.900, 0.856, 0.870], equal_var=False)
        // gives t = 8.092887, df = 2.073853, p = 0.0134108.
        let w = welch(&[0.978, 0.982, 0.984], &[0.900, 0.856, 0.870]).unwrap();
        assert!((w.difference - 0.106).abs() < 1e-9, "{w:?}");
        assert!((w.t - 8.092887).abs() < 1e-5, "{w:?}");
        assert!((w.df - 2.073853).abs() < 1e-5, "{w:?}");
        assert!((w.p - 0.0134108).abs() < 1e-6, "{w:?}");
        // Symmetric in the sign of the difference.
        let v = welch(&[0.900, 0.856, 0.870], &[0.978, 0.982, 0.984]).unwrap();
        assert!((v.p - w.p).abs() < 1e-12 && (v.t + w.t).abs() < 1e-12);
        // Equal samples: no evidence of a difference.
        let same = welch(&[1.0, 2.0, 3.0], &[1.0, 2.0, 3.0]).unwrap();
        assert!(same.t == 0.0 && (same.p - 1.0).abs() < 1e-12, "{same:?}");
        // One value, or no spread at all: no test.
        assert!(welch(&[1.0], &[1.0, 2.0]).is_none());
        assert!(welch(&[1.0, 1.0], &[2.0, 2.0]).is_none());
    }

    #[test]
    fn a_report_with_a_value_no_evaluation_writes_is_refused_by_field() {
        let a = Aggregate {
            episodes: 10,
            successes: 8,
            collisions: 1,
            timeouts: 1,
            success_time_s: 80.0,
            success_path_m: 70.0,
            danger_steps: 5,
            steps: 400,
            timeout_steps: 100,
            abs_rotation_rad: 20.0,
            return_sum: 5.0,
            ..Aggregate::default()
        };
        let good = SettingReport::new("env2-visible", &a);
        assert_eq!(good.check(), Ok(()));
        // Counts absent (a report from before they were recorded): the rates alone are checked.
        let old = SettingReport {
            successes: 0,
            collisions: 0,
            timeouts: 0,
            ..good.clone()
        };
        assert_eq!(old.check(), Ok(()));
        let refused = |f: fn(&mut SettingReport), field: &str| {
            let mut r = good.clone();
            f(&mut r);
            let e = r.check().unwrap_err();
            assert!(e.contains(field), "{field}: {e}");
        };
        refused(|r| r.setting = "env4-visible".into(), "setting");
        refused(|r| r.episodes = 0, "no episodes");
        refused(|r| r.success = 1.5, "success 1.5");
        refused(|r| r.disc = -0.1, "disc");
        refused(|r| r.timeout = f64::NAN, "timeout");
        refused(
            |r| {
                r.success = 0.9;
                r.collision = 0.1;
            },
            "not 1",
        );
        refused(
            |r| {
                r.success = 0.7;
                r.collision = 0.2;
            },
            "counts 8/1/1",
        );
        refused(|r| r.danger_steps = 401, "danger steps");
        refused(|r| r.nav_time_s = Some(-1.0), "nav_time_s");
        refused(|r| r.path_length_m = Some(f64::INFINITY), "path_length_m");
        refused(|r| r.mean_return = f64::NAN, "mean_return");
    }

    #[test]
    fn paper_numbers_and_layout() {
        let s: Setting = "env3-visible".parse().unwrap();
        assert_eq!(Metric::NavTime.paper("lstm-rl", s), Some(12.32));
        assert_eq!(Metric::Disc.paper("orca", Setting::ALL[0]), Some(0.39));
        assert_eq!(Metric::Success.paper("fsrl", s), None);
        assert_eq!(Metric::Disc.paper("sarl+foresight", s), None);
        let row = paper_row(Metric::Disc, "fsrl").unwrap();
        assert_eq!(
            row,
            "| FSRL (paper) | 0.01 | 0.07 | 0.04 | 0.04 | 0.06 | 0.08 | 0.07 | 0.07 |"
        );
        let ours = paper_layout_row(|s| (format!("{}", s.index()), Some(s.index() as f64)), 1);
        assert_eq!(ours, " 0 | 1 | 2 | 1.0 | 3 | 4 | 5 | 4.0 |");
    }

    #[test]
    fn csv_quotes() {
        assert_eq!(csv_field("a,b"), "\"a,b\"");
        assert_eq!(csv_field("say \"hi\""), "\"say \"\"hi\"\"\"");
        assert_eq!(csv_field("plain"), "plain");
    }
}
