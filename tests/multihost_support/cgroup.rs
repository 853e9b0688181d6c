//! CPU budgets for emulated hosts: one CPU cgroup per host with a quota (cgroup v1's
//! `cpu.cfs_quota_us` / `cpu.cfs_period_us` under `/sys/fs/cgroup/cpu`, or cgroup v2's `cpu.max`
//! when `/sys/fs/cgroup/cgroup.controllers` lists `cpu`), made here and removed on drop (also
//! on a panic). Groups left behind by a run that was killed (`fsrlcg<pid>-...` whose process is
//! gone) are removed by the next one. Also the CPU time of one process, from `/proc`.

use std::path::{Path, PathBuf};
use std::time::Duration;

/// The CFS period every group gets, in µs.
pub const PERIOD_US: u64 = 100_000;

/// Which cgroup interface this machine offers for the CPU controller.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Flavour {
    /// cgroup v1: the `cpu` controller's hierarchy at this path.
    V1(PathBuf),
    /// cgroup v2: the unified hierarchy at `/sys/fs/cgroup`.
    V2(PathBuf),
}

impl Flavour {
    fn root(&self) -> &Path {
        match self {
            Flavour::V1(p) | Flavour::V2(p) => p,
        }
    }
}

/// The CPU controller's hierarchy, if one is mounted where we look.
pub fn flavour() -> Option<Flavour> {
    let unified = Path::new("/sys/fs/cgroup");
    if let Ok(c) = std::fs::read_to_string(unified.join("cgroup.controllers")) {
        if c.split_whitespace().any(|x| x == "cpu") {
            return Some(Flavour::V2(unified.to_path_buf()));
        }
    }
    for p in ["/sys/fs/cgroup/cpu", "/sys/fs/cgroup/cpu,cpuacct"] {
        let p = Path::new(p);
        if p.join("cpu.cfs_quota_us").exists() {
            return Some(Flavour::V1(p.to_path_buf()));
        }
    }
    None
}

/// Why CPU cgroups with a quota cannot be made here, if they cannot (tries one).
pub fn cgroups_unavailable() -> Option<String> {
    // SAFETY: geteuid has no preconditions and cannot fail.
    if unsafe { libc::geteuid() } != 0 {
        return Some("not running as root (CPU cgroups need it)".into());
    }
    if flavour().is_none() {
        return Some(
            "no CPU cgroup controller (neither cgroup v1 /sys/fs/cgroup/cpu nor v2 with cpu in cgroup.controllers)"
                .into(),
        );
    }
    match CpuGroup::create("probe", 0.5) {
        Ok(g) => {
            drop(g);
            None
        }
        Err(e) => Some(format!("cannot make a CPU cgroup with a quota: {e}")),
    }
}

/// Throttling counters of a group (`cpu.stat`).
#[derive(Clone, Copy, Debug, Default)]
pub struct Throttling {
    /// CFS periods in which the group ran.
    pub periods: u64,
    /// Of those, periods in which it used its whole quota and was stopped.
    pub throttled: u64,
    /// Time its threads were held back, in seconds.
    pub throttled_s: f64,
}

impl Throttling {
    /// The counters accumulated between `earlier` and `self`.
    pub fn since(&self, earlier: &Throttling) -> Throttling {
        Throttling {
            periods: self.periods.saturating_sub(earlier.periods),
            throttled: self.throttled.saturating_sub(earlier.throttled),
            throttled_s: (self.throttled_s - earlier.throttled_s).max(0.0),
        }
    }

    /// Throttled periods / periods.
    pub fn fraction(&self) -> f64 {
        if self.periods == 0 {
            0.0
        } else {
            self.throttled as f64 / self.periods as f64
        }
    }
}

/// A CPU cgroup with a quota of `cores` (quota = cores × [`PERIOD_US`]), removed on drop.
pub struct CpuGroup {
    path: PathBuf,
    flavour: Flavour,
    cores: f64,
}

impl CpuGroup {
    /// Makes the group `fsrlcg<pid>-<name>` directly under the controller's root, with a quota
    /// of `cores` CPUs.
    pub fn create(name: &str, cores: f64) -> Result<Self, String> {
        if !(cores > 0.0 && cores.is_finite()) {
            return Err(format!("a quota of {cores} cores"));
        }
        let flavour = flavour().ok_or("no CPU cgroup controller")?;
        sweep_stale(&flavour);
        let path = flavour
            .root()
            .join(format!("fsrlcg{}-{name}", std::process::id()));
        if let Flavour::V2(root) = &flavour {
            // The children of the root get the cpu controller only if the root hands it down.
            let control = root.join("cgroup.subtree_control");
            let on = std::fs::read_to_string(&control).unwrap_or_default();
            if !on.split_whitespace().any(|x| x == "cpu") {
                write(&control, "+cpu")?;
            }
        }
        std::fs::create_dir(&path).map_err(|e| format!("{}: {e}", path.display()))?;
        let g = CpuGroup {
            path,
            flavour,
            cores,
        };
        let quota = (cores * PERIOD_US as f64).round() as u64;
        match &g.flavour {
            Flavour::V1(_) => {
                write(&g.path.join("cpu.cfs_period_us"), &PERIOD_US.to_string())?;
                write(&g.path.join("cpu.cfs_quota_us"), &quota.to_string())?;
            }
            Flavour::V2(_) => write(&g.path.join("cpu.max"), &format!("{quota} {PERIOD_US}"))?,
        }
        Ok(g)
    }

    /// Moves process `pid` (all its threads; threads and children it makes later follow) into
    /// the group.
    pub fn add(&self, pid: u32) -> Result<(), String> {
        write(&self.path.join("cgroup.procs"), &pid.to_string())
    }

    /// The process ids in the group now.
    pub fn pids(&self) -> Vec<u32> {
        std::fs::read_to_string(self.path.join("cgroup.procs"))
            .unwrap_or_default()
            .lines()
            .filter_map(|l| l.trim().parse().ok())
            .collect()
    }

    /// The quota, in CPUs.
    pub fn cores(&self) -> f64 {
        self.cores
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The quota as the kernel holds it, in CPUs (read back from the group's files).
    pub fn quota_read_back(&self) -> Option<f64> {
        let read = |f: &str| std::fs::read_to_string(self.path.join(f)).ok();
        let (q, p) = match &self.flavour {
            Flavour::V1(_) => (
                read("cpu.cfs_quota_us")?.trim().parse::<f64>().ok()?,
                read("cpu.cfs_period_us")?.trim().parse::<f64>().ok()?,
            ),
            Flavour::V2(_) => {
                let s = read("cpu.max")?;
                let mut w = s.split_whitespace();
                (w.next()?.parse().ok()?, w.next()?.parse().ok()?)
            }
        };
        Some(q / p)
    }

    /// The group's throttling counters so far.
    pub fn throttling(&self) -> Throttling {
        let text = std::fs::read_to_string(self.path.join("cpu.stat")).unwrap_or_default();
        let mut t = Throttling::default();
        for line in text.lines() {
            let mut w = line.split_whitespace();
            let (Some(k), Some(v)) = (w.next(), w.next().and_then(|v| v.parse::<u64>().ok()))
            else {
                continue;
            };
            match k {
                "nr_periods" => t.periods = v,
                "nr_throttled" => t.throttled = v,
                "throttled_time" => t.throttled_s = v as f64 / 1e9,
                "throttled_usec" => t.throttled_s = v as f64 / 1e6,
                _ => {}
            }
        }
        t
    }
}

impl Drop for CpuGroup {
    fn drop(&mut self) {
        remove(&self.flavour, &self.path);
    }
}

/// Removes the group at `path`: moves whatever is still in it to the root first (a group
/// with processes cannot be removed), retrying while killed processes are being reaped.
fn remove(flavour: &Flavour, path: &Path) {
    let root_procs = flavour.root().join("cgroup.procs");
    for attempt in 0..50 {
        if !path.exists() || std::fs::remove_dir(path).is_ok() {
            return;
        }
        for pid in std::fs::read_to_string(path.join("cgroup.procs"))
            .unwrap_or_default()
            .lines()
        {
            let _ = std::fs::write(&root_procs, pid.trim());
        }
        if attempt == 49 {
            eprintln!("warning: cannot remove the cgroup {}", path.display());
        }
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// Removes groups of runs whose process is gone (`fsrlcg<pid>-...`).
fn sweep_stale(flavour: &Flavour) {
    let Ok(dir) = std::fs::read_dir(flavour.root()) else {
        return;
    };
    for e in dir.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let Some(rest) = name.strip_prefix("fsrlcg") else {
            continue;
        };
        let Some(pid) = rest.split('-').next().and_then(|p| p.parse::<u32>().ok()) else {
            continue;
        };
        if !Path::new(&format!("/proc/{pid}")).exists() {
            remove(flavour, &e.path());
        }
    }
}

fn write(path: &Path, value: &str) -> Result<(), String> {
    std::fs::write(path, value).map_err(|e| format!("writing {value:?} to {}: {e}", path.display()))
}

/// CPU time (user + system, all threads) process `pid` has used so far, in seconds.
pub fn process_cpu_s(pid: u32) -> Option<f64> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // Fields after the command (which may hold spaces) in parentheses: state is field 3,
    // utime 14 and stime 15, in clock ticks.
    let rest = &stat[stat.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks = f.get(11)?.parse::<u64>().ok()? + f.get(12)?.parse::<u64>().ok()?;
    // SAFETY: sysconf has no preconditions.
    let hz = unsafe { libc::sysconf(libc::_SC_CLK_TCK) };
    Some(ticks as f64 / if hz > 0 { hz as f64 } else { 100.0 })
}
