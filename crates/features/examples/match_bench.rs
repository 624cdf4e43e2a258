//! Times brute-force descriptor matching on random unit descriptors: `match_bench [N] [DIM]`.
use handheld_features::matching::{match_descriptors, MatchOptions};
use handheld_features::Descriptors;
use std::time::Instant;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let n: usize = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(8192);
    let dim: usize = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(128);
    let mut s = 1u64;
    let mut rnd = || {
        s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((s >> 40) as f32) / (1u64 << 24) as f32
    };
    let mut make = || {
        let mut data = Vec::with_capacity(n * dim);
        for _ in 0..n {
            let v: Vec<f32> = (0..dim).map(|_| rnd()).collect();
            let norm = v.iter().map(|x| x * x).sum::<f32>().sqrt();
            data.extend(v.iter().map(|x| x / norm));
        }
        Descriptors { dim, data }
    };
    let (a, b) = (make(), make());
    let _ = match_descriptors(&a, &b, &MatchOptions::default());
    let t = Instant::now();
    let reps = 3;
    let mut found = 0;
    for _ in 0..reps {
        found = match_descriptors(&a, &b, &MatchOptions::default()).len();
    }
    let secs = t.elapsed().as_secs_f64() / reps as f64;
    let gflop = 2.0 * (n * n * dim) as f64 / 1e9;
    gemm_only(n, dim);
    println!("{{\"n\": {n}, \"dim\": {dim}, \"seconds\": {secs:.4}, \"gflops\": {:.1}, \"matches\": {found}}}", gflop / secs);
}

/// GEMM-only timings: matrixmultiply vs faer on the same shapes (rows block 256 × all columns).
#[allow(dead_code)]
pub fn gemm_only(n: usize, dim: usize) {
    let a = vec![0.5f32; n * dim];
    let b = vec![0.25f32; n * dim];
    let mut c = vec![0f32; 256 * n];
    let t = Instant::now();
    for i0 in (0..n).step_by(256) {
        unsafe {
            matrixmultiply::sgemm(
                256,
                dim,
                n,
                1.0,
                a[i0 * dim..].as_ptr(),
                dim as isize,
                1,
                b.as_ptr(),
                1,
                dim as isize,
                0.0,
                c.as_mut_ptr(),
                n as isize,
                1,
            );
        }
    }
    let mm = t.elapsed().as_secs_f64();
    let t = Instant::now();
    for i0 in (0..n).step_by(256) {
        let lhs = faer::MatRef::from_row_major_slice(&a[i0 * dim..(i0 + 256) * dim], 256, dim);
        let rhs = faer::MatRef::from_row_major_slice(&b, n, dim).transpose();
        let dst = faer::MatMut::from_row_major_slice_mut(&mut c, 256, n);
        faer::linalg::matmul::matmul(dst, faer::Accum::Replace, lhs, rhs, 1.0f32, faer::Par::Seq);
    }
    let fa = t.elapsed().as_secs_f64();
    println!("{{\"gemm_single_thread\": {{\"matrixmultiply_s\": {mm:.4}, \"faer_s\": {fa:.4}}}}}");
}
