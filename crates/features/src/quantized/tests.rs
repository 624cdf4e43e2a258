use super::*;

/// A seeded linear congruential generator of 31-bit values.
fn lcg(mut s: u64) -> impl FnMut() -> u32 {
    move || {
        s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (s >> 33) as u32
    }
}

/// Test operands with many ties: `n` and `m` rows of `dim` bytes taking three values, with every
/// `every`-th row of the second set a copy of an earlier one; each first row's `Σ q` and both
/// sets' squared norms.
#[allow(clippy::type_complexity)]
fn tied(
    rnd: &mut impl FnMut() -> u32,
    (n, m, dim): (usize, usize, usize),
    every: usize,
) -> (Vec<u8>, Vec<u8>, Vec<i32>, Vec<f32>, Vec<f32>) {
    let qa: Vec<u8> = (0..n * dim).map(|_| (rnd() % 3) as u8 * 60).collect();
    let mut qb: Vec<u8> = (0..m * dim).map(|_| (rnd() % 3) as u8 * 60).collect();
    for j in (0..m).step_by(every).skip(1) {
        let src = (rnd() as usize) % j;
        qb.copy_within(src * dim..(src + 1) * dim, j * dim);
    }
    let suma = qa
        .chunks_exact(dim)
        .map(|r| r.iter().map(|&v| i32::from(v)).sum())
        .collect();
    let sq = |v: &[u8]| v.iter().map(|&x| u32::from(x) * u32::from(x)).sum::<u32>() as f32;
    let na = qa.chunks_exact(dim).map(sq).collect();
    let nb = qb.chunks_exact(dim).map(sq).collect();
    (qa, qb, suma, na, nb)
}

/// Every score of the block `(i0, rows, j0, cols)` equals the exact integer product.
fn assert_exact(
    qa: &[u8],
    qb: &[u8],
    dim: usize,
    block: (usize, usize, usize, usize),
    out: &[f32],
) {
    let (i0, rows, j0, cols) = block;
    for r in 0..rows {
        for c in 0..cols {
            let (i, j) = (i0 + r, j0 + c);
            let exact: i64 = (0..dim)
                .map(|k| i64::from(qa[i * dim + k]) * i64::from(qb[j * dim + k]))
                .sum();
            assert_eq!(out[r * cols + c] as i64, exact, "({i}, {j})");
        }
    }
}

#[test]
#[cfg_attr(
    not(has_vnni),
    ignore = "needs a CPU with AVX-512 VNNI (this one has none)"
)]
fn vnni_scores_equal_the_exact_integer_products() {
    assert!(cpu_has_vnni(), "this CPU has no AVX-512 VNNI");
    let mut rnd = lcg(7);
    for &(n, m, dim) in &[(37usize, 53usize, 128usize), (8, 16, 128), (5, 21, 10)] {
        let qa: Vec<u8> = (0..n * dim).map(|_| rnd() as u8).collect();
        let qb: Vec<u8> = (0..m * dim).map(|_| rnd() as u8).collect();
        let suma: Vec<i32> = qa
            .chunks_exact(dim)
            .map(|r| r.iter().map(|&v| i32::from(v)).sum())
            .collect();
        let packed = PackedB::new(&qb, dim);
        let (i0, rows, j0, cols) = (1, n - 2, 16, m - 16);
        let mut out = vec![0f32; rows * cols];
        scores_block(true, &qa, &suma, dim, i0, rows, &packed, j0, cols, &mut out);
        assert_exact(&qa, &qb, dim, (i0, rows, j0, cols), &out);
    }
}

#[test]
#[cfg_attr(
    not(has_vnni),
    ignore = "needs a CPU with AVX-512 VNNI (this one has none)"
)]
fn the_fused_scan_equals_the_scores_then_the_scan_ties_included() {
    use crate::nearest::{scan_block, Best2, Block};
    assert!(cpu_has_vnni(), "this CPU has no AVX-512 VNNI");
    let mut rnd = lcg(17);
    // Partial row chunks (of 8) and tiles (of 16); few distinct values, and repeated rows and
    // columns, so that many scores tie.
    for &(n, m, dim) in &[
        (37usize, 53usize, 128usize),
        (8, 16, 128),
        (5, 37, 10),
        (70, 100, 16),
    ] {
        let (qa, qb, suma, na, nb) = tied(&mut rnd, (n, m, dim), 5);
        let packed = PackedB::new(&qb, dim);
        let (i0, rows) = (1, n - 2);
        let groups = RowGroups::new(true, &qa, dim, i0, rows);
        // Two column blocks, the second partial, the column bests carried from the first.
        let splits = [(0, 16.min(m)), (16.min(m), m - 16.min(m))];
        let mut want = vec![Best2::NONE; rows];
        let (mut wv, mut wk) = (vec![f32::NEG_INFINITY; m], vec![u32::MAX; m]);
        let mut lanes = vec![RowLanes::NONE; rows];
        let (mut gv, mut gk) = (wv.clone(), wk.clone());
        for &(j0, cols) in splits.iter().filter(|s| s.1 > 0) {
            let mut out = vec![0f32; rows * cols];
            scores_block_grouped(&groups, &suma, &packed, j0, cols, &mut out);
            let block = Block {
                s: &out,
                rows,
                cols,
                i0,
                j0,
                na: &na[i0..i0 + rows],
                nb: &nb[j0..j0 + cols],
            };
            let cb = (&mut wv[j0..j0 + cols], &mut wk[j0..j0 + cols]);
            scan_block(&block, &mut want, Some(cb));
            scan_scores_grouped(
                &groups,
                (i0, rows),
                &suma,
                &packed,
                j0,
                cols,
                &na[i0..i0 + rows],
                &nb[j0..j0 + cols],
                &mut lanes,
                Some((&mut gv[j0..j0 + cols], &mut gk[j0..j0 + cols])),
            );
        }
        let got: Vec<Best2> = lanes.iter().map(RowLanes::merge).collect();
        assert_eq!(got, want, "{n}×{m}×{dim}");
        // The whole set's layout, read from a row chunk on: the rows after the first chunk.
        if n > 9 {
            let whole = RowGroups::new(true, &qa, dim, 0, n);
            let (k0, k) = (8, n - 8);
            let mut out = vec![0f32; k * m];
            scores_block_grouped(
                &RowGroups::new(true, &qa, dim, k0, k),
                &suma,
                &packed,
                0,
                m,
                &mut out,
            );
            let block = Block {
                s: &out,
                rows: k,
                cols: m,
                i0: k0,
                j0: 0,
                na: &na[k0..],
                nb: &nb,
            };
            let mut want = vec![Best2::NONE; k];
            scan_block(&block, &mut want, None);
            let mut lanes = vec![RowLanes::NONE; k];
            scan_scores_grouped(
                &whole,
                (k0, k),
                &suma,
                &packed,
                0,
                m,
                &na[k0..],
                &nb,
                &mut lanes,
                None,
            );
            let got: Vec<Best2> = lanes.iter().map(RowLanes::merge).collect();
            assert_eq!(got, want, "from row {k0}, {n}×{m}×{dim}");
        }
        assert_eq!((gv, gk), (wv, wk), "{n}×{m}×{dim}");
        assert!(want.iter().any(|b| b.s1 == b.s2), "the case has ties");
    }
}

#[test]
fn avx_vnni_scores_equal_the_exact_integer_products() {
    if !cpu_has_avx_vnni() {
        eprintln!("skipped: this CPU has no AVX-VNNI");
        return;
    }
    let mut rnd = lcg(13);
    for &(n, m, dim, full) in &[
        (37usize, 53usize, 128usize, false),
        (8, 16, 128, false),
        (5, 37, 10, false),
        (9, 40, 128, true),
    ] {
        let mut draw = || if full { 255u8 } else { rnd() as u8 };
        let qa: Vec<u8> = (0..n * dim).map(|_| draw()).collect();
        let qb: Vec<u8> = (0..m * dim).map(|_| draw()).collect();
        let suma: Vec<i32> = qa
            .chunks_exact(dim)
            .map(|r| r.iter().map(|&v| i32::from(v)).sum())
            .collect();
        let packed = PackedB::new(&qb, dim);
        let (i0, rows, j0, cols) = (1, n - 2, 16, m - 16);
        let mut out = vec![0f32; rows * cols];
        scores_block(
            false, &qa, &suma, dim, i0, rows, &packed, j0, cols, &mut out,
        );
        assert_exact(&qa, &qb, dim, (i0, rows, j0, cols), &out);
    }
}

#[test]
fn avx2_scores_equal_the_exact_integer_products() {
    if !cpu_has_avx2() {
        eprintln!("skipped: this CPU has no AVX2");
        return;
    }
    let mut rnd = lcg(11);
    // Sizes that leave partial row groups (of 6) and partial tiles (of 16); 255s everywhere in
    // the last case, the largest sums (128 · 255², below 2²⁴).
    for &(n, m, dim, full) in &[
        (37usize, 53usize, 128usize, false),
        (8, 16, 128, false),
        (5, 37, 10, false),
        (6, 33, 9, false),
        (9, 40, 128, true),
    ] {
        let mut draw = || if full { 255u8 } else { rnd() as u8 };
        let qa: Vec<u8> = (0..n * dim).map(|_| draw()).collect();
        let qb: Vec<u8> = (0..m * dim).map(|_| draw()).collect();
        let packed = PackedI16::new(&qb, dim);
        let pa = pairs_of(&qa, dim);
        let (i0, rows, j0, cols) = (1, n - 2, 16, m - 16);
        let mut out = vec![0f32; rows * cols];
        scores_block_avx2(&pa, dim, i0, rows, &packed, j0, cols, &mut out);
        assert_exact(&qa, &qb, dim, (i0, rows, j0, cols), &out);
    }
}

#[test]
fn avx2_byte_scores_equal_the_exact_integer_products() {
    if !cpu_has_avx2() {
        eprintln!("skipped: this CPU has no AVX2");
        return;
    }
    let mut rnd = lcg(13);
    // Partial row groups (of 4), partial tiles (of 16), an odd number of four-dimension groups and
    // a partial one; then the extremes: every value 127, where the row's bytes and the set's less
    // 64 give the largest pair sums (2 · 127 · 63 per group), and every value 0 (the set's −64).
    for &(n, m, dim, fill) in &[
        (37usize, 53usize, 32usize, None),
        (8, 16, 32, None),
        (5, 37, 10, None),
        (6, 33, 7, None),
        (11, 40, 20, None),
        (9, 40, 32, Some(127u8)),
        (9, 40, 32, Some(0u8)),
    ] {
        let mut draw = || fill.unwrap_or_else(|| (rnd() % 128) as u8);
        let qa: Vec<u8> = (0..n * dim).map(|_| draw()).collect();
        let qb: Vec<u8> = (0..m * dim).map(|_| draw()).collect();
        let sums: Vec<i32> = qa
            .chunks_exact(dim)
            .map(|r| r.iter().map(|&v| i32::from(v)).sum())
            .collect();
        let packed = PackedBytes::new(&qb, dim);
        let pa = quads_of(&qa, dim);
        let (i0, rows, j0, cols) = (1, n - 2, 16, m - 16);
        let mut out = vec![0f32; rows * cols];
        scores_block_avx2_bytes(&pa, &sums, dim, i0, rows, &packed, j0, cols, &mut out);
        assert_exact(&qa, &qb, dim, (i0, rows, j0, cols), &out);
    }
}

#[test]
#[cfg_attr(
    not(has_vnni),
    ignore = "needs a CPU with AVX-512 VNNI (this one has none)"
)]
fn the_fused_coarse_scan_equals_the_scores_then_the_lane_scan_ties_included() {
    use crate::nearest::{scan_lanes2, Block, RowLanes2};
    assert!(cpu_has_vnni(), "this CPU has no AVX-512 VNNI");
    let mut rnd = lcg(23);
    for &(n, m, dim) in &[
        (37usize, 53usize, 32usize),
        (9, 16, 32),
        (70, 300, 32),
        (13, 37, 12),
    ] {
        // Few distinct values and repeated columns: many keys tie within a lane.
        let (qa, qb, suma, na, nb) = tied(&mut rnd, (n, m, dim), 7);
        let packed = PackedB::new(&qb, dim);
        let (i0, rows) = (8, n - 8);
        let groups = RowGroups::new(true, &qa, dim, 0, n);
        let (mut want, mut got) = (vec![RowLanes2::NONE; rows], vec![RowLanes2::NONE; rows]);
        // Column blocks of 256 and a partial last one, the lanes carried across them.
        for j0 in (0..m).step_by(256) {
            let cols = 256.min(m - j0);
            let mut out = vec![0f32; rows * cols];
            let rg = RowGroups::new(true, &qa, dim, i0, rows);
            scores_block_grouped(&rg, &suma, &packed, j0, cols, &mut out);
            let block = Block {
                s: &out,
                rows,
                cols,
                i0,
                j0,
                na: &na[i0..i0 + rows],
                nb: &nb[j0..j0 + cols],
            };
            scan_lanes2(&block, &mut want);
            scan_lanes2_grouped(
                &groups,
                (i0, rows),
                &suma,
                &packed,
                j0,
                cols,
                &nb[j0..j0 + cols],
                &mut got,
            );
        }
        assert_eq!(got, want, "n {n} m {m} dim {dim}");
    }
}

#[test]
#[cfg_attr(
    not(has_vnni),
    ignore = "needs a CPU with AVX-512 VNNI (this one has none)"
)]
fn sixteen_vnni_dots_equal_the_exact_integer_products() {
    assert!(cpu_has_vnni(), "this CPU has no AVX-512 VNNI");
    let mut rnd = lcg(29);
    let b: Vec<u8> = (0..40 * 128).map(|_| rnd() as u8).collect();
    for _ in 0..50 {
        let a: Vec<u8> = (0..128).map(|_| rnd() as u8).collect();
        let sum_a = a.iter().map(|&v| i32::from(v)).sum();
        let js: [u32; 16] = std::array::from_fn(|k| if k == 5 { u32::MAX } else { rnd() % 40 });
        // SAFETY: the CPU has AVX-512 VNNI (asserted above).
        let got = unsafe { dots16(&a, sum_a, &b, &js) };
        for (k, &j) in js.iter().enumerate().filter(|(_, &j)| j != u32::MAX) {
            let row = &b[j as usize * 128..(j as usize + 1) * 128];
            let exact: i32 = a
                .iter()
                .zip(row)
                .map(|(&x, &y)| i32::from(x) * i32::from(y))
                .sum();
            assert_eq!(got[k], exact, "lane {k}, row {j}");
        }
    }
}

#[test]
fn coarse_codes_are_the_projections_on_the_principal_axes() {
    // A descriptor at the mean plus t along axis c (quantised as the matcher quantises) codes to
    // 64 + round(t · s) on axis c and about 64 on the others (the axes are orthonormal; the
    // quantisation of the descriptor moves each projection by well under a code unit).
    let s = coarse_scale();
    for (c, t) in [(0usize, 0.3f32), (5, -0.2), (31, 0.1)] {
        let v: Vec<f32> = (0..128)
            .map(|k| (pca::MEAN[k] + t * pca::AXES[c][k]).clamp(0.0, 1.0))
            .collect();
        let q = quantize(&v);
        let code = coarse_codes(&q, 128).expect("128 dimensions");
        assert_eq!(code.len(), COARSE_DIM);
        for (k, &x) in code.iter().enumerate() {
            let want = if k == c { 64.0 + t * s } else { 64.0 };
            assert!(
                (f32::from(x) - want).abs() <= 3.0,
                "axis {k}: {x} against {want}"
            );
        }
    }
    assert!(coarse_codes(&[0u8; 64], 64).is_none());
    // The axes are unit vectors and orthogonal to each other.
    for a in 0..COARSE_DIM {
        for b in 0..COARSE_DIM {
            let dot: f32 = (0..128).map(|k| pca::AXES[a][k] * pca::AXES[b][k]).sum();
            let want = if a == b { 1.0 } else { 0.0 };
            assert!((dot - want).abs() < 1e-4, "axes {a}, {b}: {dot}");
        }
    }
}
