//! Evaluation reports: the paper's metrics per setting as JSON and as a Markdown table.

use serde::Serialize;
use sim::Aggregate;

/// One setting's metrics, with field names other tools can read.
#[derive(Debug, Clone, Serialize)]
pub struct SettingReport {
    pub setting: String,
    pub episodes: u32,
    pub success: f64,
    pub collision: f64,
    pub timeout: f64,
    /// Mean over successful episodes; null without a success.
    pub nav_time_s: Option<f64>,
    pub disc: f64,
    pub path_length_m: Option<f64>,
    pub mean_abs_rotation_rad: f64,
    pub mean_return: f64,
}

impl SettingReport {
    pub fn new(setting: &str, a: &Aggregate) -> Self {
        Self {
            setting: setting.to_string(),
            episodes: a.episodes,
            success: a.success_rate(),
            collision: a.collision_rate(),
            timeout: a.timeout_rate(),
            nav_time_s: a.nav_time_s(),
            disc: a.discomfort(),
            path_length_m: a.path_length_m(),
            mean_abs_rotation_rad: a.mean_abs_rotation_rad(),
            mean_return: a.mean_return(),
        }
    }
}

/// A whole report.
#[derive(Debug, Clone, Serialize)]
pub struct Report {
    pub method: String,
    pub policy_version: u64,
    pub test_seed_start: u64,
    pub settings: Vec<SettingReport>,
}

fn opt(v: Option<f64>, digits: usize) -> String {
    v.map_or_else(|| "–".to_string(), |x| format!("{x:.digits$}"))
}

impl Report {
    /// The paper's layout: Succ., Coll., Timeout, Nav. Time, Disc. per setting.
    pub fn markdown(&self) -> String {
        let mut s = format!(
            "Method `{}`, policy version {}, test seeds from {}.\n\n| setting | episodes | Succ. | Coll. | Timeout | Nav. Time (s) | Disc. | Path (m) | mean abs dθ (rad/step) |\n|---|---|---|---|---|---|---|---|---|\n",
            self.method, self.policy_version, self.test_seed_start
        );
        for r in &self.settings {
            s += &format!(
                "| {} | {} | {:.3} | {:.3} | {:.3} | {} | {:.3} | {} | {:.4} |\n",
                r.setting,
                r.episodes,
                r.success,
                r.collision,
                r.timeout,
                opt(r.nav_time_s, 2),
                r.disc,
                opt(r.path_length_m, 2),
                r.mean_abs_rotation_rad
            );
        }
        s
    }
}
