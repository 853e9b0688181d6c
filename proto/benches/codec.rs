//! Codec benchmarks: encode and decode (with full validation) of an episode batch (45 steps,
//! 10 humans) and of SARL weights (96 502 f32).

use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use proto::{decode, encode_into, fixtures, SenderId, TransitionBatch, Weights};

fn codec(c: &mut Criterion) {
    let mut g = c.benchmark_group("codec");
    g.sample_size(30);
    g.measurement_time(Duration::from_secs(3));

    let batch = fixtures::episode(45, 10, 0);
    let h = fixtures::header::<TransitionBatch>(SenderId::actor(0), 0, 1);
    let mut buf = Vec::new();
    encode_into(&h, &batch, &mut buf, usize::MAX).expect("encode");
    eprintln!("encoded batch: {} bytes", buf.len());
    g.throughput(Throughput::Bytes(buf.len() as u64));
    g.bench_function("encode_batch_45x10", |b| {
        b.iter(|| encode_into(&h, black_box(&batch), &mut buf, usize::MAX).expect("encode"))
    });
    let bytes = buf.clone();
    g.bench_function("decode_batch_45x10", |b| {
        b.iter(|| decode::<TransitionBatch>(black_box(&bytes)).expect("decode"))
    });

    let w = fixtures::sarl_weights(1);
    let h = fixtures::header::<Weights>(SenderId::learner(), 0, 1);
    encode_into(&h, &w, &mut buf, usize::MAX).expect("encode");
    eprintln!("encoded SARL weights: {} bytes", buf.len());
    g.throughput(Throughput::Bytes(buf.len() as u64));
    g.bench_function("encode_weights_sarl", |b| {
        b.iter(|| encode_into(&h, black_box(&w), &mut buf, usize::MAX).expect("encode"))
    });
    let bytes = buf.clone();
    g.bench_function("decode_weights_sarl", |b| {
        b.iter(|| decode::<Weights>(black_box(&bytes)).expect("decode"))
    });
    g.finish();
}

criterion_group!(benches, codec);
criterion_main!(benches);
