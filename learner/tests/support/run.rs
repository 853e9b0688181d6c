//! The pieces of a short learner run over zenoh on 127.0.0.1 that the learner's unit tests
//! (`process::tests`, by `#[path]`) and its integration tests (`learning::finish`) share: the
//! transports, the run's spec and a stand-in actor's episodes.

use policy::method::{Method, RunSpec, TrainConfig};
use policy::rollout::{rollout, Behaviour};
use proto::{RunId, SenderId};
use transport::{Transport, TransportConfig, ZenohConfig};

/// A transport of `run` as `sender`, listening on `port` (`listen`) or connecting to it.
pub fn transport(run: &RunId, sender: SenderId, port: u16, listen: bool) -> Transport {
    let mut cfg = TransportConfig::new(run.clone(), sender);
    let ep = format!("tcp/127.0.0.1:{port}");
    cfg.zenoh = if listen {
        ZenohConfig::peer(vec![ep], Vec::new())
    } else {
        ZenohConfig::peer(Vec::new(), vec![ep])
    };
    Transport::open(cfg).expect("transport")
}

/// SARL on env1-invisible, seed 5, trained with `train`.
pub fn spec(train: TrainConfig) -> RunSpec {
    RunSpec {
        method: Method::Sarl,
        setting: "env1-invisible".parse().unwrap(),
        sim: sim::SimConfig::default(),
        train,
        seed: 5,
    }
}

/// An honest ORCA episode of the run's setting as the actor's episode `episode`.
pub fn episode(spec: &RunSpec, episode: u64) -> proto::TransitionBatch {
    let mut env = sim::Env::new(spec.method_sim(), spec.setting, 0).unwrap();
    let orca = Behaviour::Orca {
        safety_space_m: 0.0,
    };
    let ep = rollout(&mut env, 100 + episode, orca).unwrap();
    policy::wire::to_batch(&ep, episode, env.action_set().len() as u16).unwrap()
}
