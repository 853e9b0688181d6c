//! Bounds-checked wrapper around `gemm` for strided f32 matrices, and small dense helpers,
//! shared by the inference path and the fused dfdx linear op; and [`dense_packed`], the
//! inference path's AVX-512 layer kernel that sums exactly as `gemm` does (issue 54).

/// A read-only strided matrix view: element `(i, j)` is `data[i · rs + j · cs]`.
#[derive(Clone, Copy, Debug)]
pub(crate) struct View<'a> {
    pub data: &'a [f32],
    pub rs: usize,
    pub cs: usize,
}

impl<'a> View<'a> {
    /// Row-major with row stride `ld`.
    pub fn rows(data: &'a [f32], ld: usize) -> Self {
        View {
            data,
            rs: ld,
            cs: 1,
        }
    }

    /// The transpose of a row-major matrix with row stride `ld`.
    pub fn transposed(data: &'a [f32], ld: usize) -> Self {
        View {
            data,
            rs: 1,
            cs: ld,
        }
    }

    fn check(&self, rows: usize, cols: usize, what: &str) {
        if rows > 0 && cols > 0 {
            let last = (rows - 1) * self.rs + (cols - 1) * self.cs;
            assert!(last < self.data.len(), "gemm: {what} view too short");
        }
    }
}

/// Threading of one product.
#[derive(Clone, Copy, Debug)]
pub(crate) enum Threads {
    /// The calling thread only.
    One,
    /// `gemm` over `rayon::current_num_threads()` threads (as dfdx does).
    Rayon,
}

/// `c (m × n, row-major, row stride ldc) = [c +] a (m × k) · b (k × n)`.
#[allow(clippy::too_many_arguments)]
pub(crate) fn gemm(
    m: usize,
    n: usize,
    k: usize,
    c: &mut [f32],
    ldc: usize,
    a: View<'_>,
    b: View<'_>,
    accumulate: bool,
    threads: Threads,
) {
    if m == 0 || n == 0 {
        return;
    }
    assert!(
        ldc >= n && c.len() >= (m - 1) * ldc + n,
        "gemm: output too short"
    );
    if k == 0 {
        if !accumulate {
            for r in 0..m {
                c[r * ldc..r * ldc + n].fill(0.0);
            }
        }
        return;
    }
    a.check(m, k, "lhs");
    b.check(k, n, "rhs");
    let parallelism = match threads {
        Threads::One => gemm::Parallelism::None,
        Threads::Rayon => gemm::Parallelism::Rayon(0),
    };
    // SAFETY: the checks above keep every element the product reads ((m−1)·rs + (k−1)·cs of
    // `a`, likewise `b`) or writes ((m−1)·ldc + n − 1 of `c`) inside its slice; `c` is a unique
    // borrow, so it aliases neither input.
    unsafe {
        gemm::gemm(
            m,
            n,
            k,
            c.as_mut_ptr(),
            1,
            ldc as isize,
            accumulate,
            a.data.as_ptr(),
            a.cs as isize,
            a.rs as isize,
            b.data.as_ptr(),
            b.cs as isize,
            b.rs as isize,
            if accumulate { 1.0 } else { 0.0 },
            1.0,
            false,
            false,
            false,
            parallelism,
        );
    }
}

/// Dot product with 8 independent accumulators (vectorises without fast-math).
#[inline]
pub(crate) fn dot(a: &[f32], b: &[f32]) -> f32 {
    let mut acc = [0.0f32; 8];
    let whole = a.len().min(b.len()) / 8 * 8;
    for (x, y) in a[..whole].chunks_exact(8).zip(b[..whole].chunks_exact(8)) {
        for j in 0..8 {
            acc[j] += x[j] * y[j];
        }
    }
    let mut s = acc.iter().sum::<f32>();
    for (x, y) in a[whole..].iter().zip(&b[whole..]) {
        s += x * y;
    }
    s
}

#[inline]
pub(crate) fn relu_inplace(v: &mut [f32]) {
    for x in v {
        *x = x.max(0.0);
    }
}

/// `out[j] += Σ_r g[r · n + j]` (column sums of a dense `rows × n` matrix).
pub(crate) fn add_column_sums(g: &[f32], n: usize, out: &mut [f32]) {
    for row in g.chunks_exact(n) {
        for (o, v) in out.iter_mut().zip(row) {
            *o += v;
        }
    }
}

/// Output features per chunk of [`PackedMat`]: three 16-lane vectors.
const CHUNK: usize = 48;
/// Rows per register tile of [`dense_packed`] (8 rows × 3 vectors = 24 accumulators of the 32
/// AVX-512 registers, so that none spills).
const TILE_ROWS: usize = 8;
/// Rows per block: a block's inputs stay in cache while every chunk of features runs over it.
const ROW_BLOCK: usize = 96;

/// A weight matrix `w (n × k)` (row `f` holds output feature `f`'s weights) packed once for
/// [`dense_packed`]: chunks of [`CHUNK`] features, each stored `k × width` (feature fastest,
/// zero-padded to the chunk's vector width: 48, 32 or 16, or 8 for a last chunk of ≤ 8).
#[derive(Clone, Debug)]
pub(crate) struct PackedMat {
    n: usize,
    k: usize,
    data: Vec<f32>,
}

/// The stored width of a chunk of `w` features.
fn stored_width(w: usize) -> usize {
    if w <= 8 {
        8
    } else {
        w.div_ceil(16) * 16
    }
}

impl PackedMat {
    /// Packs `w`: `n` rows of `k` weights, row `f` at `data[f · ld..]`.
    pub fn new(data: &[f32], ld: usize, n: usize, k: usize) -> Self {
        assert!(
            n > 0 && k > 0 && (n - 1) * ld + k <= data.len(),
            "pack: too short"
        );
        let mut out = Vec::new();
        for f0 in (0..n).step_by(CHUNK) {
            let w = CHUNK.min(n - f0);
            let sw = stored_width(w);
            for kk in 0..k {
                out.extend((0..sw).map(|j| if j < w { data[(f0 + j) * ld + kk] } else { 0.0 }));
            }
        }
        PackedMat { n, k, data: out }
    }
}

/// Whether [`dense_packed`] runs here (AVX-512F/VL with FMA). Elsewhere the callers use
/// [`gemm`], whose results these equal bit for bit (see [`dense_packed`]).
pub(crate) fn packed_kernels() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx512f")
            && std::arch::is_x86_feature_detected!("avx512vl")
            && std::arch::is_x86_feature_detected!("fma")
    }
    #[cfg(not(target_arch = "x86_64"))]
    false
}

/// `out[r][f] = act(init[r / group][f] + Σ_k a[r][k] · w[f][k])` for `m` rows (`a` of row
/// stride `lda`, `out` dense `m × n`; `group = usize::MAX` for one bias row). Only where
/// [`packed_kernels`] holds (panics otherwise).
///
/// Bit for bit what [`gemm`] (the `gemm` crate's FMA kernels) computes for `init` copied into
/// `out` and accumulated into, followed by [`relu_inplace`]: for `k ≤ 512` the crate sums each
/// element in one pass, `acc = 0; acc = fma(w, a, acc)` for `k` ascending, then `out + acc`;
/// this kernel does exactly that per element, only with larger register tiles, the weights
/// packed once instead of per call, and the bias and ReLU in the same pass
/// (`fast::tests::packed_kernels_equal_gemm_bit_for_bit`). So `k` must be in `3..=512` (below 3
/// the crate takes another path).
///
/// **Zero inputs are skipped.** A tile of eight rows leaves out every `k` where all eight inputs
/// are zero: `fma(w, ±0, acc)` is `acc` for any finite `w` and any `acc` but `−0`, and `acc` is
/// never `−0` here (it starts at `+0`, and `+0 + −0 = +0`), so the sums are the same bit for bit.
/// The inputs of SARL's layers after the first are ReLU outputs, 62–83 % zeros in the
/// lookahead's batches (issue 54). `alike` rows per sample (`m` a multiple of it; 1 otherwise)
/// groups a tile's rows as row `h` of eight consecutive samples instead of eight consecutive
/// rows: the same person in the lookahead's neighbouring states, whose zeros mostly coincide
/// (57–79 % of a tile's inputs skipped, against 32–64 % for consecutive rows). Only the order in
/// which rows are computed changes; each row's output is where it always was.
#[allow(clippy::too_many_arguments)]
pub(crate) fn dense_packed(
    m: usize,
    a: &[f32],
    lda: usize,
    w: &PackedMat,
    init: &[f32],
    group: usize,
    relu: bool,
    out: &mut [f32],
    alike: usize,
) {
    let (n, k) = (w.n, w.k);
    assert!(
        (3..=512).contains(&k),
        "dense_packed: k = {k} outside 3..=512"
    );
    assert!(packed_kernels(), "dense_packed: no AVX-512 here");
    if m == 0 {
        return;
    }
    assert!(
        lda >= k && a.len() >= (m - 1) * lda + k,
        "dense_packed: input too short"
    );
    assert!(group > 0, "dense_packed: group 0");
    assert!(
        init.len() >= ((m - 1) / group + 1) * n,
        "dense_packed: init too short"
    );
    assert!(out.len() >= m * n, "dense_packed: output too short");
    let alike = if alike > 1 && m.is_multiple_of(alike) {
        alike
    } else {
        1
    };
    // SAFETY: the features were detected above; the asserts keep every read of `a` (rows
    // < m, columns < k), `init` (row (m−1)/group at most, columns < n) and write of `out`
    // (m × n) in bounds; `w.data` holds every chunk at its stored width for all k; `alike`
    // divides `m`, so every row index the kernel forms is below `m`.
    #[cfg(target_arch = "x86_64")]
    unsafe {
        avx512::dense(
            m,
            a.as_ptr(),
            lda,
            w,
            init.as_ptr(),
            group,
            relu,
            out.as_mut_ptr(),
            alike,
        );
    }
}

#[cfg(target_arch = "x86_64")]
mod avx512 {
    // The functions below are unsafe for their raw pointers and target features: callers
    // check both (`super::dense_packed`); their bodies are one unsafe block each.
    #![allow(unsafe_op_in_unsafe_fn)]
    use super::{stored_width, PackedMat, CHUNK, ROW_BLOCK, TILE_ROWS};
    use std::arch::x86_64::*;

    /// Tiles per row block.
    const TILES: usize = ROW_BLOCK / TILE_ROWS;

    /// See [`super::dense_packed`]; the caller checked the features and bounds, and that
    /// `alike` divides `m`.
    #[target_feature(enable = "avx512f,avx512vl,fma")]
    #[allow(clippy::too_many_arguments)]
    pub(super) unsafe fn dense(
        m: usize,
        a: *const f32,
        lda: usize,
        w: &PackedMat,
        init: *const f32,
        group: usize,
        relu: bool,
        out: *mut f32,
        alike: usize,
    ) {
        let (n, k) = (w.n, w.k);
        let samples = m / alike;
        // Row computed in place `l`: row `l / samples` of sample `l % samples`.
        let row_at = |l: usize| (l % samples) * alike + l / samples;
        let mut rows = [[0usize; TILE_ROWS]; TILES];
        let mut live = [0usize; TILES];
        let mut inputs = [[0u16; 512]; TILES];
        let mut counts = [0usize; TILES];
        for lb in (0..m).step_by(ROW_BLOCK) {
            let lb_end = (lb + ROW_BLOCK).min(m);
            let tiles = (lb_end - lb).div_ceil(TILE_ROWS);
            for t in 0..tiles {
                let l0 = lb + t * TILE_ROWS;
                live[t] = TILE_ROWS.min(lb_end - l0);
                // Rows past the end repeat the last row (computed, never stored).
                rows[t] = std::array::from_fn(|r| row_at(l0 + r.min(live[t] - 1)));
                counts[t] = nonzero_inputs(a, lda, k, &rows[t][..live[t]], &mut inputs[t]);
            }
            let mut off = 0;
            for f0 in (0..n).step_by(CHUNK) {
                let width = CHUNK.min(n - f0);
                let sw = stored_width(width);
                let wp = w.data.as_ptr().add(off);
                for t in 0..tiles {
                    let tile = Tile {
                        inputs: &inputs[t][..counts[t]],
                        a,
                        lda,
                        rix: rows[t],
                        rows: live[t],
                        wp,
                        init,
                        group,
                        n,
                        f0,
                        width,
                        relu,
                        out,
                    };
                    match sw {
                        48 => tile_z::<3>(&tile),
                        32 => tile_z::<2>(&tile),
                        16 => tile_z::<1>(&tile),
                        _ => tile_y(&tile),
                    }
                }
                off += sw * k;
            }
        }
    }

    /// The inputs `k` at which some row of `rows` is not zero (NaN counts as not zero), in
    /// ascending order, into `list`; returns how many.
    #[target_feature(enable = "avx512f,avx512vl,fma")]
    #[inline]
    unsafe fn nonzero_inputs(
        a: *const f32,
        lda: usize,
        k: usize,
        rows: &[usize],
        list: &mut [u16; 512],
    ) -> usize {
        let zero = _mm512_setzero_ps();
        let mut len = 0;
        for k0 in (0..k).step_by(16) {
            let lanes = (k - k0).min(16);
            let lm = if lanes == 16 {
                u16::MAX
            } else {
                (1u16 << lanes) - 1
            };
            let mut nz: u16 = 0;
            for &r in rows {
                let v = _mm512_maskz_loadu_ps(lm, a.add(r * lda + k0));
                nz |= _mm512_mask_cmp_ps_mask::<_CMP_NEQ_UQ>(lm, v, zero);
            }
            let mut bits = nz;
            while bits != 0 {
                list[len] = (k0 + bits.trailing_zeros() as usize) as u16;
                len += 1;
                bits &= bits - 1;
            }
        }
        len
    }

    /// One register tile: rows `rix[..rows]` (≤ 8) × features `f0..f0 + width`, summed over
    /// `inputs` only.
    struct Tile<'a> {
        inputs: &'a [u16],
        a: *const f32,
        lda: usize,
        rix: [usize; TILE_ROWS],
        rows: usize,
        wp: *const f32,
        init: *const f32,
        group: usize,
        n: usize,
        f0: usize,
        width: usize,
        relu: bool,
        out: *mut f32,
    }

    impl Tile<'_> {
        /// Row pointers of the tile's inputs.
        #[inline(always)]
        unsafe fn rows(&self) -> [*const f32; TILE_ROWS] {
            std::array::from_fn(|r| self.a.add(self.rix[r] * self.lda))
        }

        /// Lanes of vector `v` (of `lanes` each) inside the tile's width, as a mask.
        #[inline(always)]
        fn mask(&self, v: usize, lanes: usize) -> u16 {
            let live = self.width.saturating_sub(v * lanes).min(lanes);
            if live >= 16 {
                u16::MAX
            } else {
                (1u16 << live) - 1
            }
        }
    }

    /// `NV` 16-lane vectors of features per row.
    #[target_feature(enable = "avx512f,avx512vl,fma")]
    #[inline]
    unsafe fn tile_z<const NV: usize>(t: &Tile) {
        let ap = t.rows();
        let mut acc = [[_mm512_setzero_ps(); NV]; TILE_ROWS];
        let stride = NV * 16;
        for &kk in t.inputs {
            let kk = kk as usize;
            let wrow = t.wp.add(kk * stride);
            let wv: [__m512; NV] = std::array::from_fn(|v| _mm512_loadu_ps(wrow.add(v * 16)));
            for r in 0..TILE_ROWS {
                let b = _mm512_set1_ps(*ap[r].add(kk));
                for v in 0..NV {
                    acc[r][v] = _mm512_fmadd_ps(wv[v], b, acc[r][v]);
                }
            }
        }
        let zero = _mm512_setzero_ps();
        for (r, acc) in acc.iter().enumerate().take(t.rows) {
            let row = t.rix[r];
            let ip = t.init.add((row / t.group) * t.n + t.f0);
            let op = t.out.add(row * t.n + t.f0);
            for (v, &acc) in acc.iter().enumerate() {
                let mask = t.mask(v, 16);
                let c = _mm512_maskz_loadu_ps(mask, ip.add(v * 16));
                let mut o = _mm512_add_ps(c, acc);
                if t.relu {
                    // maxps returns its second operand for NaN and for ±0: as `f32::max(x, 0)`.
                    o = _mm512_max_ps(o, zero);
                }
                _mm512_mask_storeu_ps(op.add(v * 16), mask, o);
            }
        }
    }

    /// One 8-lane vector of features per row (a last chunk of ≤ 8 features).
    #[target_feature(enable = "avx512f,avx512vl,fma")]
    #[inline]
    unsafe fn tile_y(t: &Tile) {
        let ap = t.rows();
        let mut acc = [_mm256_setzero_ps(); TILE_ROWS];
        for &kk in t.inputs {
            let kk = kk as usize;
            let wv = _mm256_loadu_ps(t.wp.add(kk * 8));
            for r in 0..TILE_ROWS {
                let b = _mm256_set1_ps(*ap[r].add(kk));
                acc[r] = _mm256_fmadd_ps(wv, b, acc[r]);
            }
        }
        let zero = _mm256_setzero_ps();
        let mask = t.mask(0, 8) as u8;
        for (r, &acc) in acc.iter().enumerate().take(t.rows) {
            let row = t.rix[r];
            let ip = t.init.add((row / t.group) * t.n + t.f0);
            let op = t.out.add(row * t.n + t.f0);
            let c = _mm256_maskz_loadu_ps(mask, ip);
            let mut o = _mm256_add_ps(c, acc);
            if t.relu {
                o = _mm256_max_ps(o, zero);
            }
            _mm256_mask_storeu_ps(op, mask, o);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// Over shapes around every chunk and tile edge (n from 2 to 150, k from 3 to 160, 1 to 41
    /// rows, input row strides above k, one bias row or a row per group of rows, ReLU on and
    /// off, rows per sample 1, 4 and 5), with dense inputs and with ReLU-like sparse ones (some
    /// inputs zero, +0 or −0, in every row of a sample-aligned tile and some only in a few; bias
    /// values ±0 among them), the packed kernel's outputs equal `gemm` after the same initial
    /// values (then `relu_inplace`) bit for bit. Skipped where the packed kernels do not run.
    #[test]
    fn packed_kernel_equals_gemm_bit_for_bit() {
        if !packed_kernels() {
            eprintln!("no AVX-512 here: the packed kernels do not run, nothing to compare");
            return;
        }
        let mut rng = ChaCha8Rng::seed_from_u64(54);
        let mut compared = 0;
        let mut skipped_inputs = 0;
        for &n in &[
            2, 4, 7, 8, 9, 16, 17, 31, 33, 47, 48, 49, 50, 64, 96, 100, 101, 150,
        ] {
            for &k in &[3, 6, 13, 50, 100, 150, 160] {
                for &m in &[1, 7, 8, 9, 40, 41, 120] {
                    let lda = k + rng.gen_range(0..3);
                    let ld = k + rng.gen_range(0..3);
                    let group = [usize::MAX, 1, 5][rng.gen_range(0..3)];
                    let alike = [1, 4, 5][rng.gen_range(0..3)];
                    let relu = rng.gen_bool(0.5);
                    let sparse = rng.gen_bool(0.6);
                    let mut v = |len: usize, scale: f32| -> Vec<f32> {
                        (0..len).map(|_| rng.gen_range(-scale..scale)).collect()
                    };
                    let mut a = v(m * lda, 2.0);
                    let w = v(n * ld, 0.5);
                    let init_rows = if group == usize::MAX {
                        1
                    } else {
                        (m - 1) / group + 1
                    };
                    let mut init = v(init_rows * n, 1.0);
                    if sparse {
                        // Inputs dead for every row, and for single rows, as a ReLU leaves them.
                        let dead: Vec<bool> = (0..k).map(|_| rng.gen_bool(0.6)).collect();
                        for r in 0..m {
                            for c in 0..k {
                                if dead[c] || rng.gen_bool(0.3) {
                                    a[r * lda + c] = if rng.gen_bool(0.5) { 0.0 } else { -0.0 };
                                }
                            }
                        }
                        skipped_inputs += dead.iter().filter(|&&d| d).count();
                        for x in init.iter_mut() {
                            if rng.gen_bool(0.1) {
                                *x = if rng.gen_bool(0.5) { 0.0 } else { -0.0 };
                            }
                        }
                    }
                    let mut want: Vec<f32> = (0..m)
                        .flat_map(|r| {
                            let i = r / group;
                            init[i * n..(i + 1) * n].to_vec()
                        })
                        .collect();
                    gemm(
                        m,
                        n,
                        k,
                        &mut want,
                        n,
                        View::rows(&a, lda),
                        View::transposed(&w, ld),
                        true,
                        Threads::One,
                    );
                    if relu {
                        relu_inplace(&mut want);
                    }
                    let packed = PackedMat::new(&w, ld, n, k);
                    let mut got = vec![f32::NAN; m * n];
                    dense_packed(m, &a, lda, &packed, &init, group, relu, &mut got, alike);
                    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                    assert_eq!(
                        bits(&got),
                        bits(&want),
                        "m {m} n {n} k {k} group {group} alike {alike} sparse {sparse}"
                    );
                    compared += m * n;
                }
            }
        }
        assert!(compared > 100_000, "{compared}");
        assert!(skipped_inputs > 10_000, "{skipped_inputs}");
    }
}
