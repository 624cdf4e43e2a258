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
        let qa: Vec<u8> = (0..n * dim).map(|_| (rnd() % 3) as u8 * 60).collect();
        let mut qb: Vec<u8> = (0..m * dim).map(|_| (rnd() % 3) as u8 * 60).collect();
        for j in (0..m).step_by(5).skip(1) {
            let src = (rnd() as usize) % j;
            qb.copy_within(src * dim..(src + 1) * dim, j * dim);
        }
        let suma: Vec<i32> = qa
            .chunks_exact(dim)
            .map(|r| r.iter().map(|&v| i32::from(v)).sum())
            .collect();
        let sq = |v: &[u8]| v.iter().map(|&x| u32::from(x) * u32::from(x)).sum::<u32>() as f32;
        let na: Vec<f32> = qa.chunks_exact(dim).map(sq).collect();
        let nb: Vec<f32> = qb.chunks_exact(dim).map(sq).collect();
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
