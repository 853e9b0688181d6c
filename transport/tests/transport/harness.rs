//! Test networks: N transports of one run on loopback, for either backend.

use std::path::Path;
use std::time::Duration;

use proto::{RunId, SenderId};
use testkit::free_port;
use transport::{DataPlane, Transport, TransportConfig, ZenohConfig};

/// Generous bound for anything that should happen "at once" on a loaded 2-core machine.
pub const WAIT: Duration = Duration::from_secs(10);

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Backend {
    Zenoh,
    Iceoryx2,
}

/// One run: a hub transport listens on a free loopback port; the others connect to it.
pub struct Net {
    pub backend: Backend,
    pub run: RunId,
    pub prefix: String,
    pub endpoint: String,
    hub_opened: bool,
}

impl Net {
    pub fn new(backend: Backend) -> Self {
        let id: u64 = rand::random();
        Self {
            backend,
            run: RunId::new(format!("t{id:016x}")).expect("run id"),
            prefix: format!("fsrlt{id:016x}_"),
            endpoint: String::new(),
            hub_opened: false,
        }
    }

    pub fn config(&self, sender: SenderId) -> TransportConfig {
        let mut c = TransportConfig::new(self.run.clone(), sender);
        c.data_plane = match self.backend {
            Backend::Zenoh => DataPlane::Zenoh,
            Backend::Iceoryx2 => DataPlane::Iceoryx2,
        };
        c.iceoryx2.prefix = Some(self.prefix.clone());
        c.iceoryx2.max_processes = 8;
        c.zenoh = ZenohConfig::peer(vec!["tcp/127.0.0.1:0".into()], vec![self.endpoint.clone()]);
        c
    }

    /// Opens a transport; the first one opened is the hub (listens on a fixed free port).
    pub fn open_with(&mut self, mut config: TransportConfig) -> Transport {
        if self.hub_opened {
            config.zenoh.connect = vec![self.endpoint.clone()];
            return Transport::open(config).expect("open transport");
        }
        // The port may be taken between probing and binding: retry with another.
        let mut last = None;
        for _ in 0..5 {
            let endpoint = format!("tcp/127.0.0.1:{}", free_port());
            config.zenoh.listen = vec![endpoint.clone()];
            config.zenoh.connect = Vec::new();
            match Transport::open(config.clone()) {
                Ok(t) => {
                    self.endpoint = endpoint;
                    self.hub_opened = true;
                    return t;
                }
                Err(e) => last = Some(e),
            }
        }
        panic!("cannot open hub transport: {last:?}");
    }

    pub fn open(&mut self, sender: SenderId) -> Transport {
        let c = self.config(sender);
        self.open_with(c)
    }

    /// `/dev/shm` entries carrying this net's iceoryx2 prefix.
    pub fn shm_entries(&self) -> Vec<String> {
        shm_entries_with(&self.prefix)
    }
}

pub fn shm_entries_with(prefix: &str) -> Vec<String> {
    let Ok(dir) = std::fs::read_dir(Path::new("/dev/shm")) else {
        return Vec::new();
    };
    dir.filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.contains(prefix))
        .collect()
}

/// Runs a suite function for both backends as two tests.
#[macro_export]
macro_rules! both_backends {
    ($($name:ident),* $(,)?) => {
        mod zenoh_backend {
            $(#[test] fn $name() { super::$name($crate::harness::Backend::Zenoh) })*
        }
        mod iceoryx2_backend {
            $(#[test] fn $name() { super::$name($crate::harness::Backend::Iceoryx2) })*
        }
    };
}
