use std::time::{Duration, Instant};
use proto::{fixtures, keys, RunId, SenderId, TransitionBatch};
use transport::{DataPlane, Transport, TransportConfig, ZenohConfig};

#[test]
fn stress_raw_iceoryx2() {
    let id: u64 = rand::random();
    let run = RunId::new(format!("s{id:016x}")).unwrap();
    let mk = |s| {
        let mut c = TransportConfig::new(run.clone(), s);
        c.data_plane = DataPlane::Iceoryx2;
        c.iceoryx2.prefix = Some(format!("fsrls{id:016x}_"));
        c.iceoryx2.max_processes = 8;
        c.publish_timeout_ms = 3000;
        c.zenoh = ZenohConfig::peer(vec!["tcp/127.0.0.1:0".into()], vec![]);
        Transport::open(c).unwrap()
    };
    let learner = mk(SenderId::learner());
    let actor = mk(SenderId::actor(0));
    let sub = learner.subscriber(&keys::all_transitions(&run)).unwrap();
    let publisher = actor.publisher(&keys::transitions(&run, 0)).unwrap();
    let batch = fixtures::episode(45, 10, 0);
    let header = proto::Header::new::<TransitionBatch>(run.clone(), SenderId::actor(0), 0, 1);
    let bytes = proto::encode(&header, &batch).unwrap();
    let total: u64 = 3_000_000;
    let t0 = Instant::now();
    std::thread::scope(|s| {
        let r = s.spawn(|| {
            let mut n = 0u64;
            while n < total {
                match sub.recv_bytes_timeout(Duration::from_secs(5), |b| b.len()) {
                    Ok(Some(_)) => n += 1,
                    Ok(None) => { eprintln!("receiver: nothing for 5 s after {n}"); return n; }
                    Err(e) => { eprintln!("receiver error after {n}: {e}"); return n; }
                }
            }
            n
        });
        for i in 0..total {
            if let Err(e) = publisher.publish_raw(bytes.clone()) {
                eprintln!("publisher error at {i}: {e}");
                break;
            }
        }
        let n = r.join().unwrap();
        eprintln!("received {n} in {:?}", t0.elapsed());
        assert_eq!(n, total);
    });
}
