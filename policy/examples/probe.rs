use dfdx::prelude::*;
use std::time::Instant;

fn gemm_nn(m: usize, n: usize, k: usize, a: &[f32], b: &[f32], c: &mut [f32]) {
    // row-major: c (m x n) = a (m x k) * b (k x n)
    unsafe {
        gemm::gemm(m, n, k, c.as_mut_ptr(), 1, n as isize, false, a.as_ptr(), 1, k as isize,
            b.as_ptr(), 1, n as isize, 0.0, 1.0, false, false, false, gemm::Parallelism::None);
    }
}
fn gemm_nt(m: usize, n: usize, k: usize, a: &[f32], b: &[f32], c: &mut [f32]) {
    // c (m x n) = a (m x k) * b^T, b is (n x k) row-major
    unsafe {
        gemm::gemm(m, n, k, c.as_mut_ptr(), 1, n as isize, false, a.as_ptr(), 1, k as isize,
            b.as_ptr(), k as isize, 1, 0.0, 1.0, false, false, false, gemm::Parallelism::None);
    }
}

fn time<F: FnMut()>(name: &str, flops: f64, reps: usize, mut f: F) {
    for _ in 0..reps / 10 + 1 { f(); }
    let t = Instant::now();
    for _ in 0..reps { f(); }
    let dt = t.elapsed().as_secs_f64() / reps as f64;
    println!("{name:40} {:9.2} us  {:6.1} GFLOP/s", dt * 1e6, flops / dt / 1e9);
}

fn main() {
    run_peak();
    for &(m, n, k) in &[(512, 512, 512), (256,256,256), (510, 150, 13), (510, 100, 150), (510, 200, 100), (510, 100, 100), (510, 50, 100), (1000,100,150), (51,150,56)] {
        let a = vec![0.5f32; m * k];
        let b = vec![0.25f32; k * n];
        let mut c = vec![0.0f32; m * n];
        let fl = 2.0 * (m * n * k) as f64;
        time(&format!("gemm nn {m}x{n}x{k}"), fl, 200, || gemm_nn(m, n, k, &a, &b, &mut c));
        time(&format!("gemm nt {m}x{n}x{k}"), fl, 200, || gemm_nt(m, n, k, &a, &b, &mut c));
    }
    let dev: Cpu = Default::default();
    let x: Tensor<(usize, usize), f32, Cpu> = dev.tensor_from_vec(vec![0.1f32; 1000 * 150], (1000, 150));
    let w: Tensor<(usize, usize), f32, Cpu> = dev.tensor_from_vec(vec![0.1f32; 100 * 150], (100, 150));
    let b: Tensor<(usize,), f32, Cpu> = dev.tensor_from_vec(vec![0.1f32; 100], (100,));
    let fl = 2.0 * 1000.0 * 100.0 * 150.0;
    time("dfdx matmul x w^T 1000x100x150", fl, 200, || { let _y = x.clone().matmul(w.clone().permute::<_, Axes2<1, 0>>()); });
    let y = x.clone().matmul(w.clone().permute::<_, Axes2<1, 0>>());
    time("dfdx bias add bcast 1000x100", 0.0, 200, || { let _z = y.clone() + b.clone().broadcast_like::<_, Axis<0>>(&y); });
    time("dfdx relu 1000x100", 0.0, 200, || { let _z = y.clone().relu(); });
    time("dfdx add same 1000x100", 0.0, 200, || { let _z = y.clone() + y.clone(); });
    time("dfdx lin+relu fwd+bwd traced", 3.0 * fl, 100, || {
        let xt = x.leaky_trace();
        let z = xt.matmul(w.retaped::<OwnedTape<f32, Cpu>>().permute::<_, Axes2<1, 0>>());
        let z = (z + b.retaped::<OwnedTape<f32, Cpu>>().broadcast_like::<_, Axis<0>>(&(1000usize, 100usize))).relu();
        let l = z.sum::<Rank0, _>();
        let g = l.backward();
        let _gw = g.get(&w);
    });
}

#[target_feature(enable = "avx2,fma")]
unsafe fn fma_peak(iters: usize) -> f32 {
    use std::arch::x86_64::*;
    let mut acc = [_mm256_set1_ps(0.0); 10];
    let a = _mm256_set1_ps(1.000001);
    let b = _mm256_set1_ps(0.999999);
    for _ in 0..iters {
        for r in acc.iter_mut() { *r = _mm256_fmadd_ps(*r, a, b); }
    }
    let mut s = 0.0;
    for r in acc { let mut o = [0f32; 8]; unsafe { _mm256_storeu_ps(o.as_mut_ptr(), r) }; s += o.iter().sum::<f32>(); }
    s
}
#[test]
fn peak() {}
pub fn run_peak() {
    let iters = 100_000_000usize;
    let t = Instant::now();
    let s = unsafe { fma_peak(iters) };
    let dt = t.elapsed().as_secs_f64();
    println!("fma peak: {:.1} GFLOP/s ({s})", (iters * 10 * 16) as f64 / dt / 1e9);
}
