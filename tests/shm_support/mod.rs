//! What processes leave behind in /dev/shm: take a snapshot before starting them and list what
//! is new afterwards. Shared by tests/distributed.rs, tests/multihost.rs and
//! benches/scaling.rs.

/// The names in /dev/shm at one moment.
pub struct ShmSnapshot(Vec<String>);

impl ShmSnapshot {
    pub fn take() -> Self {
        Self(entries())
    }

    /// Names that are in /dev/shm now, were not at the snapshot, and satisfy `keep`.
    pub fn new_since(&self, keep: impl Fn(&str) -> bool) -> Vec<String> {
        entries()
            .into_iter()
            .filter(|e| !self.0.contains(e) && keep(e))
            .collect()
    }
}

fn entries() -> Vec<String> {
    std::fs::read_dir("/dev/shm")
        .map(|d| {
            d.flatten()
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .collect()
        })
        .unwrap_or_default()
}
