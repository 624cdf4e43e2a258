//! Semi-Global Matching cost aggregation (Hirschmüller, "Stereo Processing by Semiglobal Matching
//! and Mutual Information", PAMI 2008, "Cost Aggregation").
//!
//! Along each path direction `r` (eq. 13):
//!
//! `L_r(p, d) = C(p, d) + min(L_r(p−r, d), L_r(p−r, d±1) + P1, min_i L_r(p−r, i) + P2)`
//! `− min_k L_r(p−r, k)`
//!
//! and the aggregated cost is `S(p, d) = Σ_r L_r(p, d)` (eq. 14). Each `L_r ≤ C_max + P2`, so `S`
//! fits in `u16` for 8 paths when `P2 ≤ 7935` (checked by [`crate::StereoOptions::validate`]).
//!
//! Two passes cover the paths: the forward pass visits rows top to bottom and pixels left to right
//! (paths from the left, top-left, top, top-right), the backward pass the reverse. The passes run
//! in parallel (rayon) into two `u16` volumes that winner-take-all sums on the fly. Only the
//! previous row of each path is kept (`3 · width · (ndisp + 2)` values), so memory is the cost
//! volume (1 byte per entry) plus the two pass sums (2 bytes each): 5 bytes per pixel and
//! disparity.
//!
//! With per-pixel disparity windows (coarse-to-fine matching, [`CostVolume::base`]) index `k`
//! means `d = base(p) + k`, so a predecessor whose window starts elsewhere is first shifted onto
//! `p`'s window; disparities it did not search enter as unreachable except through the `P2` jump
//! from its minimum (tSGM's treatment of neighbouring ranges, Rothermel et al. 2012).

use crate::cost::CostVolume;

/// Penalties of one SGM run.
pub(crate) struct SgmParams {
    pub p1: u16,
    /// `P2` as a function of the intensity step `|ΔI|` (0..=255) between `p` and `p − r`.
    pub p2_lut: [u16; 256],
    pub eight_paths: bool,
}

impl SgmParams {
    /// Constant `P2`, or `max(P1 + 1, P2 / (1 + |ΔI| / scale))` when `adaptive_scale` is given
    /// (Hirschmüller 2008, "Cost Aggregation": `P2 = P2' / |I_bp − I_bq|`, kept bounded for small
    /// steps).
    pub fn new(p1: u16, p2: u16, adaptive_scale: Option<f32>, eight_paths: bool) -> Self {
        let mut p2_lut = [p2; 256];
        if let Some(s) = adaptive_scale {
            for (i, v) in p2_lut.iter_mut().enumerate() {
                let a = f32::from(p2) / (1.0 + i as f32 / s);
                *v = (a.round() as u16).max(p1 + 1);
            }
        }
        Self {
            p1,
            p2_lut,
            eight_paths,
        }
    }
}

/// The two pass sums of a band; `S(p, d) = fwd(p, d) + bwd(p, d)` (eq. 14).
pub(crate) struct Aggregated {
    /// Forward-pass sums, same layout as the cost volume.
    pub fwd: Vec<u16>,
    /// Backward-pass sums with the pixel order reversed (pixel `p` of `n` at `n − 1 − p`,
    /// disparities in natural order), so that the backward pass writes sequentially.
    pub bwd: Vec<u16>,
}

/// Runs both passes over a band in parallel. `grey` holds the band's left image rows as `u8`
/// (for the adaptive P2). `reuse` provides storage whose capacity is kept (its contents are
/// overwritten).
pub(crate) fn aggregate(
    cost: &CostVolume,
    grey: &[u8],
    params: &SgmParams,
    reuse: Aggregated,
) -> Aggregated {
    let Aggregated { mut fwd, mut bwd } = reuse;
    // L_r ≤ C + P2 on every path, so the sum of all paths fits in u16 (checked by validate()).
    let p2_max = params.p2_lut.iter().copied().max().unwrap_or(0) as usize;
    let paths = if params.eight_paths { 8 } else { 4 };
    debug_assert!(paths * (usize::from(cost.max_cost) + p2_max) <= usize::from(u16::MAX));
    rayon::join(
        || pass(cost, grey, params, true, &mut fwd),
        || pass(cost, grey, params, false, &mut bwd),
    );
    Aggregated { fwd, bwd }
}

const BIG: u16 = u16::MAX;

/// The predecessor `L_r(p − r, ·)` of one path at one pixel: padded costs, their minimum, and the
/// `P2` for the step to `p`.
#[derive(Clone, Copy)]
struct Pred<'a> {
    l: &'a [u16],
    min: u16,
    p2: u16,
}

/// The previous row of the row-to-row paths, from which their predecessors are taken.
struct RowPreds<'a> {
    prev: &'a [u16],
    prev_min: &'a [u16],
    w: usize,
    np: usize,
    lut: &'a [u16; 256],
}

impl<'a> RowPreds<'a> {
    /// Predecessor of path `j` at previous-row abscissa `xp` (`start` outside the image or on the
    /// first row, where `g_prev` is `None`), with the predecessor's first disparity.
    #[inline(always)]
    fn get(
        &self,
        g_prev: Option<&[u8]>,
        g: u8,
        xp: isize,
        j: usize,
        start: Pred<'a>,
    ) -> (Pred<'a>, Option<usize>) {
        match g_prev {
            Some(gp) if xp >= 0 && (xp as usize) < self.w => {
                let xp = xp as usize;
                let k = j * self.w + xp;
                let p = Pred {
                    l: &self.prev[k * self.np..(k + 1) * self.np],
                    min: self.prev_min[k],
                    p2: self.lut[g.abs_diff(gp[xp]) as usize],
                };
                (p, Some(xp))
            }
            _ => (start, None),
        }
    }
}

/// `src` (padded costs of a window starting at disparity `b_src`) re-indexed onto a window of
/// the same width starting at `b_dst`, into `dst`, pads included (the `d ± 1` neighbours just
/// outside `dst`'s window may lie inside `src`'s); disparities `src` does not hold are `BIG`.
#[inline]
fn shift_into(dst: &mut [u16], src: &[u16], b_src: i32, b_dst: i32) {
    let np = src.len() as i64;
    let s = i64::from(b_dst) - i64::from(b_src);
    dst.fill(BIG);
    // dst[j] = src[j + s] for 0 ≤ j, j + s < np.
    let j0 = (-s).max(0);
    let j1 = (np - s).min(np);
    if j1 > j0 {
        let (j0, j1) = (j0 as usize, j1 as usize);
        let from = (j0 as i64 + s) as usize;
        dst[j0..j1].copy_from_slice(&src[from..from + (j1 - j0)]);
    }
}

/// Row predecessor `p` (at `xp` of row `pr`, or a path start) aligned on the window starting at
/// `b`.
#[inline(always)]
fn row_aligned<'a>(
    p: Pred<'a>,
    xp: Option<usize>,
    ranged: bool,
    cost: &CostVolume,
    pr: usize,
    b: i32,
    scratch: &'a mut [u16],
) -> Pred<'a> {
    match xp {
        Some(xp) if ranged => aligned(p, cost.base(xp, pr), b, scratch),
        _ => p,
    }
}

/// `p`, or its copy shifted from window start `b_src` to `b_dst` in `scratch` when they differ.
#[inline(always)]
fn aligned<'a>(p: Pred<'a>, b_src: i32, b_dst: i32, scratch: &'a mut [u16]) -> Pred<'a> {
    if b_src == b_dst {
        return p;
    }
    shift_into(scratch, p.l, b_src, b_dst);
    Pred { l: scratch, ..p }
}

/// One SGM pass: the horizontal path plus the vertical (and, with 8 paths, both diagonal) paths
/// arriving from the previous row, summed per pixel and appended to `out` (cleared first) in
/// visiting order.
///
/// A path with no predecessor (image border) starts from an all-zero one, for which eq. 13 gives
/// `L_r = C`, so every pixel runs the same fused kernel over all its paths.
fn pass(cost: &CostVolume, grey: &[u8], params: &SgmParams, forward: bool, out: &mut Vec<u16>) {
    let (w, rows, nd) = (cost.width, cost.rows, cost.ndisp);
    let np = nd + 2;
    let eight = params.eight_paths;
    // Row-to-row paths: with 8 paths the diagonal from x − 1, the vertical, the diagonal from
    // x + 1 (in visiting order); with 4 the vertical only.
    let offsets: &[isize] = if eight { &[-1, 0, 1] } else { &[0] };
    let nrow = offsets.len();
    out.clear();
    out.reserve(cost.data.len());
    let mut zero = vec![0; np];
    zero[0] = BIG;
    zero[np - 1] = BIG;
    let mut prev = vec![BIG; nrow * w * np];
    let mut cur = vec![BIG; nrow * w * np];
    let mut prev_min = vec![0; nrow * w];
    let mut cur_min = vec![0; nrow * w];
    let mut h_prev = vec![BIG; np];
    let mut h_cur = vec![BIG; np];
    // Shifted copies of the four predecessors (per-pixel windows only).
    let ranged = !cost.base.is_empty();
    let mut sh = [vec![BIG; np], vec![BIG; np], vec![BIG; np], vec![BIG; np]];
    let p1 = params.p1;
    let lut = params.p2_lut;
    // Sums of one row, in visiting order, appended to `out` when the row is done.
    let mut orow = vec![0u16; w * nd];
    for step in 0..rows {
        let r = if forward { step } else { rows - 1 - step };
        let pr = if forward { r.wrapping_sub(1) } else { r + 1 };
        let g = &grey[r * w..(r + 1) * w];
        let g_prev = (step > 0).then(|| &grey[pr * w..(pr + 1) * w]);
        let mut h_min = 0;
        for i in 0..w {
            let x = if forward { i } else { w - 1 - i };
            let c = cost.pixel(x, r);
            let start = Pred {
                l: &zero,
                min: 0,
                p2: lut[0],
            };
            let b = cost.base(x, r);
            let [s0, s1, s2, s3] = &mut sh;
            let h = if i == 0 {
                start
            } else {
                let xp = if forward { x - 1 } else { x + 1 };
                let p = Pred {
                    l: &h_prev,
                    min: h_min,
                    p2: lut[g[x].abs_diff(g[xp]) as usize],
                };
                if ranged {
                    aligned(p, cost.base(xp, r), b, s0)
                } else {
                    p
                }
            };
            // A row predecessor, aligned on this pixel's window.
            let row_pred = |(p, xp), scratch| row_aligned(p, xp, ranged, cost, pr, b, scratch);
            let rp = RowPreds {
                prev: &prev,
                prev_min: &prev_min,
                w,
                np,
                lut: &lut,
            };
            let xi = x as isize;
            let sum = &mut orow[i * nd..(i + 1) * nd];
            if eight {
                let (c0, rest) = cur.split_at_mut(w * np);
                let (c1, c2) = rest.split_at_mut(w * np);
                let px = x * np..(x + 1) * np;
                let m = fused4(
                    c,
                    p1,
                    [
                        h,
                        row_pred(rp.get(g_prev, g[x], xi + offsets[0], 0, start), s1),
                        row_pred(rp.get(g_prev, g[x], xi + offsets[1], 1, start), s2),
                        row_pred(rp.get(g_prev, g[x], xi + offsets[2], 2, start), s3),
                    ],
                    [
                        &mut h_cur,
                        &mut c0[px.clone()],
                        &mut c1[px.clone()],
                        &mut c2[px],
                    ],
                    sum,
                );
                h_min = m[0];
                cur_min[x] = m[1];
                cur_min[w + x] = m[2];
                cur_min[2 * w + x] = m[3];
            } else {
                let v = row_pred(rp.get(g_prev, g[x], xi, 0, start), s1);
                let m = fused2(
                    c,
                    p1,
                    [h, v],
                    [&mut h_cur, &mut cur[x * np..(x + 1) * np]],
                    sum,
                );
                h_min = m[0];
                cur_min[x] = m[1];
            }
            std::mem::swap(&mut h_prev, &mut h_cur);
        }
        out.extend_from_slice(&orow);
        std::mem::swap(&mut prev, &mut cur);
        std::mem::swap(&mut prev_min, &mut cur_min);
    }
}

/// Eq. 13 for four paths at one pixel, fused with their sum (eq. 14). `Pred::l` and `dst` are
/// padded with `BIG` at both ends so that `d ± 1` needs no special case. Returns each path's
/// `min_d L_r(p, d)`.
#[inline(always)]
fn fused4(c: &[u8], p1: u16, pr: [Pred; 4], dst: [&mut [u16]; 4], sum: &mut [u16]) -> [u16; 4] {
    let nd = c.len();
    let sum = &mut sum[..nd];
    let [a, b, e, f] = pr;
    let (a0, a1, a2) = (&a.l[0..nd], &a.l[1..nd + 1], &a.l[2..nd + 2]);
    let (b0, b1, b2) = (&b.l[0..nd], &b.l[1..nd + 1], &b.l[2..nd + 2]);
    let (e0, e1, e2) = (&e.l[0..nd], &e.l[1..nd + 1], &e.l[2..nd + 2]);
    let (f0, f1, f2) = (&f.l[0..nd], &f.l[1..nd + 1], &f.l[2..nd + 2]);
    let [da, db, de, df] = dst;
    let (da, db) = (&mut da[1..nd + 1], &mut db[1..nd + 1]);
    let (de, df) = (&mut de[1..nd + 1], &mut df[1..nd + 1]);
    let cap = |p: &Pred| p.min.saturating_add(p.p2);
    let (ca, cb, ce, cf) = (cap(&a), cap(&b), cap(&e), cap(&f));
    let mut m = [BIG; 4];
    for d in 0..nd {
        let cd = u16::from(c[d]);
        let va = a1[d].min(a0[d].min(a2[d]).saturating_add(p1)).min(ca) - a.min + cd;
        let vb = b1[d].min(b0[d].min(b2[d]).saturating_add(p1)).min(cb) - b.min + cd;
        let ve = e1[d].min(e0[d].min(e2[d]).saturating_add(p1)).min(ce) - e.min + cd;
        let vf = f1[d].min(f0[d].min(f2[d]).saturating_add(p1)).min(cf) - f.min + cd;
        da[d] = va;
        db[d] = vb;
        de[d] = ve;
        df[d] = vf;
        m[0] = m[0].min(va);
        m[1] = m[1].min(vb);
        m[2] = m[2].min(ve);
        m[3] = m[3].min(vf);
        sum[d] = va + vb + ve + vf;
    }
    m
}

/// [`fused4`] for two paths (the 4-path mode's horizontal and vertical).
#[inline(always)]
fn fused2(c: &[u8], p1: u16, pr: [Pred; 2], dst: [&mut [u16]; 2], sum: &mut [u16]) -> [u16; 2] {
    let nd = c.len();
    let sum = &mut sum[..nd];
    let [a, b] = pr;
    let (a0, a1, a2) = (&a.l[0..nd], &a.l[1..nd + 1], &a.l[2..nd + 2]);
    let (b0, b1, b2) = (&b.l[0..nd], &b.l[1..nd + 1], &b.l[2..nd + 2]);
    let [da, db] = dst;
    let (da, db) = (&mut da[1..nd + 1], &mut db[1..nd + 1]);
    let (ca, cb) = (a.min.saturating_add(a.p2), b.min.saturating_add(b.p2));
    let mut m = [BIG; 2];
    for d in 0..nd {
        let cd = u16::from(c[d]);
        let va = a1[d].min(a0[d].min(a2[d]).saturating_add(p1)).min(ca) - a.min + cd;
        let vb = b1[d].min(b0[d].min(b2[d]).saturating_add(p1)).min(cb) - b.min + cd;
        da[d] = va;
        db[d] = vb;
        m[0] = m[0].min(va);
        m[1] = m[1].min(vb);
        sum[d] = va + vb;
    }
    m
}

/// Eq. 13 for one path at one pixel (reference for the fused kernels' tests).
#[cfg(test)]
fn update(prev: &[u16], prev_min: u16, c: &[u8], p1: u16, p2: u16, dst: &mut [u16]) -> u16 {
    let mut sum = vec![0u16; c.len()];
    let pr = Pred {
        l: prev,
        min: prev_min,
        p2,
    };
    let mut scratch = vec![BIG; c.len() + 2];
    fused2(c, p1, [pr, pr], [dst, &mut scratch], &mut sum)[0]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn volume(
        w: usize,
        rows: usize,
        nd: usize,
        mut f: impl FnMut(usize, usize, usize) -> u8,
    ) -> CostVolume {
        let mut data = Vec::with_capacity(w * rows * nd);
        for r in 0..rows {
            for x in 0..w {
                for k in 0..nd {
                    data.push(f(x, r, k));
                }
            }
        }
        CostVolume {
            width: w,
            rows,
            ndisp: nd,
            min_disparity: 0,
            max_cost: 255,
            data,
            base: Vec::new(),
        }
    }

    #[test]
    fn update_follows_eq_13() {
        let prev = [BIG, 5, 9, 30, 8, BIG];
        let c = [1u8, 2, 3, 4];
        let mut dst = [BIG; 6];
        let m = update(&prev, 5, &c, 2, 10, &mut dst);
        // d0: min(5, 9+2, 15) − 5 + 1 = 1; d1: min(9, 5+2, 15) − 5 + 2 = 4;
        // d2: min(30, 8+2, 15) − 5 + 3 = 8; d3: min(8, 30+2, 15) − 5 + 4 = 7.
        assert_eq!(dst, [BIG, 1, 4, 8, 7, BIG]);
        assert_eq!(m, 1);
    }

    /// Eq. 13–14 evaluated naively, one path direction at a time, on each pixel's window
    /// (`v.base`, or `min_disparity` everywhere): a predecessor's disparity outside its own
    /// window is unreachable except by the `P2` jump.
    fn reference(v: &CostVolume, grey: &[u8], params: &SgmParams) -> Vec<u32> {
        let (w, h, nd) = (v.width as i64, v.rows as i64, v.ndisp);
        let dirs: &[(i64, i64)] = if params.eight_paths {
            &[
                (1, 0),
                (-1, 0),
                (0, 1),
                (0, -1),
                (1, 1),
                (-1, -1),
                (-1, 1),
                (1, -1),
            ]
        } else {
            &[(1, 0), (-1, 0), (0, 1), (0, -1)]
        };
        let mut s = vec![0u32; v.data.len()];
        for &(dx, dy) in dirs {
            let mut l = vec![0u32; v.data.len()];
            let ys: Vec<i64> = if dy >= 0 {
                (0..h).collect()
            } else {
                (0..h).rev().collect()
            };
            let xs: Vec<i64> = if dx >= 0 {
                (0..w).collect()
            } else {
                (0..w).rev().collect()
            };
            for &y in &ys {
                for &x in &xs {
                    let p = (y * w + x) as usize;
                    let (qx, qy) = (x - dx, y - dy);
                    let c = v.pixel(x as usize, y as usize);
                    if qx < 0 || qy < 0 || qx >= w || qy >= h {
                        for d in 0..nd {
                            l[p * nd + d] = u32::from(c[d]);
                        }
                        continue;
                    }
                    let q = (qy * w + qx) as usize;
                    let lq = &l[q * nd..(q + 1) * nd].to_vec();
                    let shift = v.base(x as usize, y as usize) - v.base(qx as usize, qy as usize);
                    // L(q, ·) at this pixel's index k, if q searched that disparity.
                    let at = |k: i64| {
                        let kq = k + i64::from(shift);
                        (0..nd as i64).contains(&kq).then(|| lq[kq as usize])
                    };
                    let m = *lq.iter().min().unwrap();
                    let p2 = u32::from(params.p2_lut[grey[p].abs_diff(grey[q]) as usize]);
                    let p1 = u32::from(params.p1);
                    for d in 0..nd {
                        let k = d as i64;
                        let mut best = m + p2;
                        if let Some(a) = at(k) {
                            best = best.min(a);
                        }
                        for e in [at(k - 1), at(k + 1)].into_iter().flatten() {
                            best = best.min(e + p1);
                        }
                        l[p * nd + d] = u32::from(c[d]) + best - m;
                    }
                }
            }
            s.iter_mut().zip(&l).for_each(|(s, l)| *s += l);
        }
        s
    }

    #[test]
    fn passes_match_the_naive_path_recursion() {
        let (w, h, nd) = (13, 9, 7);
        let mut seed = 7u32;
        let mut rnd = move || {
            seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            seed >> 24
        };
        let mut v = volume(w, h, nd, |_, _, _| (rnd() % 40) as u8);
        let grey: Vec<u8> = (0..w * h).map(|_| rnd() as u8).collect();
        // Whole range, then per-pixel windows whose starts differ by up to ±9 (more than the
        // width, so some neighbours share no disparity at all).
        let bases: Vec<i32> = (0..w * h).map(|_| (rnd() % 19) as i32 - 9).collect();
        for ranged in [false, true] {
            if ranged {
                v.base = bases.clone();
            }
            for eight in [true, false] {
                let params = SgmParams::new(4, 30, Some(16.0), eight);
                let empty = Aggregated {
                    fwd: Vec::new(),
                    bwd: Vec::new(),
                };
                let s = aggregate(&v, &grey, &params, empty);
                let want = reference(&v, &grey, &params);
                let n = w * h;
                for p in 0..n {
                    for d in 0..nd {
                        let got =
                            u32::from(s.fwd[p * nd + d]) + u32::from(s.bwd[(n - 1 - p) * nd + d]);
                        assert_eq!(
                            got,
                            want[p * nd + d],
                            "pixel {p}, d {d}, eight {eight}, ranged {ranged}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn aggregation_fills_in_an_ambiguous_pixel() {
        // True disparity 3 everywhere except one pixel whose cost is flat: SGM makes its
        // aggregated minimum sit at 3 too.
        let v = volume(9, 7, 8, |x, r, k| {
            if (x, r) == (4, 3) {
                20
            } else if k == 3 {
                0
            } else {
                20
            }
        });
        let grey = vec![100u8; 9 * 7];
        for eight in [true, false] {
            let empty = Aggregated {
                fwd: Vec::new(),
                bwd: Vec::new(),
            };
            let s = aggregate(&v, &grey, &SgmParams::new(5, 40, Some(16.0), eight), empty);
            let p = 3 * 9 + 4;
            let n = 9 * 7;
            let px: Vec<u16> = (0..8)
                .map(|k| s.fwd[p * 8 + k] + s.bwd[(n - 1 - p) * 8 + k])
                .collect();
            let best = (0..8).min_by_key(|k| px[*k]).unwrap();
            assert_eq!(best, 3, "{px:?}");
        }
    }
}
