//! A uniform grid over one image's keypoints, for the epipolar-band queries of guided matching
//! (Table 1 step 4, [`crate::guided::guided_matches`]).

use nalgebra::Vector3;

use crate::detector::Features;

/// A uniform grid over the keypoints of one image, for epipolar-band queries, stored compactly
/// (cell offsets into one index array) twice: row-major for steep lines, column-major for flat
/// ones, so that the cells a band crosses in one strip are always one range of the index.
pub(crate) struct Grid {
    cell: f64,
    cols: usize,
    rows: usize,
    /// Centre of the keypoints' extent.
    pub(crate) mid: (f64, f64),
    /// Row-major (`by_row`) and column-major (`by_col`) layouts.
    by_row: Layout,
    by_col: Layout,
}

/// The keypoints' extent: one past the largest coordinates, at least 1 × 1.
fn extent(f: &Features) -> (f64, f64) {
    let (mut w, mut h) = (1.0f64, 1.0f64);
    for k in &f.keypoints {
        w = w.max(k.x as f64 + 1.0);
        h = h.max(k.y as f64 + 1.0);
    }
    (w, h)
}

/// One layout of the grid: the keypoints of cell `c` are `index[start[c]..start[c + 1]]`.
pub(crate) struct Layout {
    pub(crate) start: Vec<u32>,
    pub(crate) index: Vec<u32>,
    /// The position of `index[k]`, in the same order (the band test reads them in sequence).
    pub(crate) xy: Vec<[f64; 2]>,
}

impl Layout {
    pub(crate) fn new(
        f: &Features,
        cells: usize,
        cell_of: impl Fn(&crate::detector::Keypoint) -> Option<usize>,
    ) -> Self {
        let mut start = vec![0u32; cells + 1];
        for k in &f.keypoints {
            if let Some(c) = cell_of(k) {
                start[c + 1] += 1;
            }
        }
        for c in 0..cells {
            start[c + 1] += start[c];
        }
        let mut fill = start.clone();
        let mut index = vec![0u32; start[cells] as usize];
        for (idx, k) in f.keypoints.iter().enumerate() {
            if let Some(c) = cell_of(k) {
                index[fill[c] as usize] = idx as u32;
                fill[c] += 1;
            }
        }
        let xy = index
            .iter()
            .map(|&i| {
                let k = &f.keypoints[i as usize];
                [k.x as f64, k.y as f64]
            })
            .collect();
        Self { start, index, xy }
    }
}

/// Keypoints per cell, on average, of [`Grid::for_keypoints`].
const KEYPOINTS_PER_CELL: f64 = 4.0;

impl Grid {
    /// A grid whose cells hold [`KEYPOINTS_PER_CELL`] keypoints on average (cells 8–64 px): a band
    /// query then walks few strips and tests few keypoints whatever the image's size and
    /// keypoint density. fountain-P11's matches stage (2 cores) took 1.49–1.51 s with any cell from
    /// 24 to 48 px, 1.57 s with 16 px and 1.60 s with 10 px.
    pub(crate) fn for_keypoints(f: &Features) -> Self {
        let (w, h) = extent(f);
        let n = f.keypoints.len().max(1) as f64;
        Self::new(f, (KEYPOINTS_PER_CELL * w * h / n).sqrt().clamp(8.0, 64.0))
    }

    pub(crate) fn new(f: &Features, cell: f64) -> Self {
        let (w, h) = extent(f);
        let cols = (w / cell).ceil() as usize + 1;
        let rows = (h / cell).ceil() as usize + 1;
        let cell_xy = |k: &crate::detector::Keypoint| {
            let (cx, cy) = (
                (k.x.max(0.0) as f64 / cell) as usize,
                (k.y.max(0.0) as f64 / cell) as usize,
            );
            (cx < cols && cy < rows).then_some((cx, cy))
        };
        Self {
            cell,
            cols,
            rows,
            mid: (w / 2.0, h / 2.0),
            by_row: Layout::new(f, cols * rows, |k| cell_xy(k).map(|(x, y)| y * cols + x)),
            by_col: Layout::new(f, cols * rows, |k| cell_xy(k).map(|(x, y)| x * rows + y)),
        }
    }

    /// The keypoints whose distance from the line `l` is at most `band` pixels, each as the
    /// caller would measure it (`|l·(x, y, 1)| / ‖(l₀, l₁)‖`), in the order of [`Grid::near_line`]:
    /// the same cell walk with the band test done on positions stored in cell order, so that a
    /// query returns its few keypoints instead of every one in the cells the band crosses
    /// (fountain-P11: about 16 of 85).
    pub(crate) fn within_band(&self, l: &Vector3<f64>, band: f64, out: &mut Vec<u32>) {
        out.clear();
        let test = BandTest::new(l, band);
        self.walk(l, band, |layout, range| {
            for k in range {
                let [x, y] = layout.xy[k];
                if test.holds(x, y) {
                    out.push(layout.index[k]);
                }
            }
        });
    }

    /// Keypoints within `band` pixels of the line `l` (`l·(x, y, 1) = 0`), plus some a little
    /// farther: walks the grid in strips across the line (rows for steep lines, columns for flat
    /// ones) and, in each strip, only the cells the band crosses inside it.
    pub(crate) fn near_line(&self, l: &Vector3<f64>, band: f64, out: &mut Vec<u32>) {
        out.clear();
        self.walk(l, band, |layout, range| {
            out.extend_from_slice(&layout.index[range])
        });
    }

    /// Walks the grid in strips across the line `l` (rows for steep lines, columns for flat
    /// ones) and hands `visit` the keypoints (a range of the layout's `index`: row-major for
    /// steep lines, column-major for flat ones) of the cells the band of `band` pixels crosses
    /// inside each strip, in order, one range per strip.
    fn walk(
        &self,
        l: &Vector3<f64>,
        band: f64,
        mut visit: impl FnMut(&Layout, std::ops::Range<usize>),
    ) {
        let n = (l.x * l.x + l.y * l.y).sqrt();
        if n < 1e-300 {
            return;
        }
        let steep = l.x.abs() >= l.y.abs();
        let (outer, inner) = if steep {
            (self.rows, self.cols)
        } else {
            (self.cols, self.rows)
        };
        // Along the outer axis the line's inner coordinate is t(s) = −(b·s + c)/a; the band is
        // ±band·n/|a| around it.
        let (a, b) = if steep { (l.x, l.y) } else { (l.y, l.x) };
        // In cell units: the line's inner coordinate at the start of strip o is u0 + o·du, and the
        // band is ±h around it. Truncation toward zero stands in for floor: it differs only below
        // zero, where the range is clamped to 0 anyway (or comes out empty, or one cell wider).
        let inv_cell = 1.0 / self.cell;
        let h = band * n / a.abs() * inv_cell;
        let du = -b / a;
        let u0 = -l.z / a * inv_cell;
        let last = inner as i64 - 1;
        for o in 0..outer {
            let (t0, t1) = (u0 + du * o as f64, u0 + du * (o + 1) as f64);
            let lo = ((t0.min(t1) - h) as i64).max(0);
            let hi = ((t0.max(t1) + h) as i64).min(last);
            if hi < lo {
                continue;
            }
            let (lo, hi) = (lo as usize, hi as usize);
            // The strip's cells are consecutive in the layout that runs along it: one range.
            let (layout, c0, c1) = if steep {
                (&self.by_row, o * self.cols + lo, o * self.cols + hi)
            } else {
                (&self.by_col, o * self.rows + lo, o * self.rows + hi)
            };
            visit(
                layout,
                layout.start[c0] as usize..layout.start[c1 + 1] as usize,
            );
        }
    }
}

/// The band test `|l·(x, y, 1)| / ‖(l₀, l₁)‖ ≤ band`, exactly as the caller measures it, without
/// a division for all but the keypoints at the band's edge: `|l·x|` is compared with `band·n`
/// widened and narrowed by far more than the rounding of either side, and only a keypoint between
/// the two bounds is divided. (The division was most of a band query's cost where the epipole
/// lies inside the image and the grid is walked: kitti-seq1.)
struct BandTest {
    l: [f64; 3],
    n: f64,
    band: f64,
    /// `band·n` less and more than the rounding can move either side of the test.
    inside: f64,
    outside: f64,
}

impl BandTest {
    fn new(l: &Vector3<f64>, band: f64) -> Self {
        let n = (l.x * l.x + l.y * l.y).sqrt();
        let t = band * n;
        Self {
            l: [l.x, l.y, l.z],
            n,
            band,
            inside: t * (1.0 - 1e-9),
            outside: t * (1.0 + 1e-9),
        }
    }

    #[inline]
    fn holds(&self, x: f64, y: f64) -> bool {
        let v = (self.l[0] * x + self.l[1] * y + self.l[2]).abs();
        v <= self.inside || (v <= self.outside && v / self.n <= self.band)
    }
}

/// Image 2's keypoints sorted by their direction from the epipole, for the band queries of
/// guided matching when the epipole lies far outside the keypoints' extent (sideways motion, most
/// orbits). Every epipolar line passes through the epipole, so the keypoints within `band` of one
/// lie in a narrow wedge about it: two binary searches find them, where [`Grid::within_band`]
/// walks one strip of cells after another across the image (most of a query's cost on
/// fountain-P11). The same exact test decides, so a query returns the same keypoints.
pub(crate) struct Pencil {
    /// The epipole, and the unit direction from it to the centre of the keypoints' extent.
    e: [f64; 2],
    axis: [f64; 2],
    /// The epipole's distance from the keypoints' bounding box.
    r_min: f64,
    /// Direction of each keypoint from the epipole (radians from `axis`), ascending, with its
    /// index and position.
    phi: Vec<f64>,
    index: Vec<u32>,
    xy: Vec<[f64; 2]>,
}

impl Pencil {
    /// The pencil of `f`'s lines in image 2 (`f` maps points of image 1 to lines of image 2), or
    /// `None` where the epipole is at infinity, or nearer the keypoints' bounding box than its
    /// diagonal (the grid serves those).
    pub(crate) fn new(f2: &Features, f: &nalgebra::Matrix3<f64>) -> Option<Self> {
        let e = epipole(f)?;
        let (lo, hi) = bounds(f2);
        let diag = ((hi[0] - lo[0]).powi(2) + (hi[1] - lo[1]).powi(2)).sqrt();
        if !(diag.is_finite() && diag > 0.0) {
            return None;
        }
        let dx = (lo[0] - e[0]).max(e[0] - hi[0]).max(0.0);
        let dy = (lo[1] - e[1]).max(e[1] - hi[1]).max(0.0);
        let r_min = (dx * dx + dy * dy).sqrt();
        // Far enough that every keypoint lies within 30° of the axis; not so far that the
        // directions lose their precision.
        if !(r_min >= diag && r_min < 1e9 * diag) {
            return None;
        }
        let c = [(lo[0] + hi[0]) / 2.0 - e[0], (lo[1] + hi[1]) / 2.0 - e[1]];
        let nc = (c[0] * c[0] + c[1] * c[1]).sqrt();
        let axis = [c[0] / nc, c[1] / nc];
        let angle =
            |v: [f64; 2]| (axis[0] * v[1] - axis[1] * v[0]).atan2(axis[0] * v[0] + axis[1] * v[1]);
        let mut order: Vec<(f64, u32)> = f2
            .keypoints
            .iter()
            .enumerate()
            .map(|(i, k)| (angle([k.x as f64 - e[0], k.y as f64 - e[1]]), i as u32))
            .collect();
        order.sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        Some(Self {
            e,
            axis,
            r_min,
            phi: order.iter().map(|p| p.0).collect(),
            index: order.iter().map(|p| p.1).collect(),
            xy: order
                .iter()
                .map(|p| {
                    let k = &f2.keypoints[p.1 as usize];
                    [k.x as f64, k.y as f64]
                })
                .collect(),
        })
    }

    /// [`Grid::within_band`]: the keypoints whose distance from `l` is at most `band` pixels,
    /// measured as the caller would, in the order of their direction from the epipole.
    pub(crate) fn within_band(&self, l: &Vector3<f64>, band: f64, out: &mut Vec<u32>) {
        out.clear();
        let n = (l.x * l.x + l.y * l.y).sqrt();
        if n < 1e-300 {
            return;
        }
        // `l` passes within `miss` of the epipole (F's rank 2 in exact arithmetic only): a keypoint
        // within `band` of `l` lies within `band + miss` of the parallel line through the
        // epipole, at a direction within asin((band + miss) / r) of that line's, r ≥ r_min its
        // distance from the epipole.
        let miss = ((l.x * self.e[0] + l.y * self.e[1] + l.z) / n).abs();
        let s = (band + miss) / self.r_min;
        if s.is_nan() || s >= 0.5 {
            // A band as wide as the wedge (or a line with no direction): test every keypoint.
            let test = BandTest::new(l, band);
            for (k, &[x, y]) in self.xy.iter().enumerate() {
                if test.holds(x, y) {
                    out.push(self.index[k]);
                }
            }
            return;
        }
        let mut u = [l.y / n, -l.x / n];
        if u[0] * self.axis[0] + u[1] * self.axis[1] < 0.0 {
            u = [-u[0], -u[1]];
        }
        let phi = (self.axis[0] * u[1] - self.axis[1] * u[0])
            .atan2(self.axis[0] * u[0] + self.axis[1] * u[1]);
        // Widened against rounding: the exact test below decides.
        let w = s.asin() * (1.0 + 1e-6) + 1e-12;
        let lo = self.phi.partition_point(|&p| p < phi - w);
        let hi = self.phi.partition_point(|&p| p <= phi + w);
        let test = BandTest::new(l, band);
        for k in lo..hi.max(lo) {
            let [x, y] = self.xy[k];
            if test.holds(x, y) {
                out.push(self.index[k]);
            }
        }
    }
}

/// Image 2's keypoints by their direction around the epipole, for the band queries of guided
/// matching when the epipole lies inside the keypoints' extent or near it (forward motion: a
/// car's camera, a walk through a corridor), where [`Pencil`] does not apply. Every epipolar
/// line passes through the epipole, so a keypoint at least `r` from it and within `band` of a
/// line lies within asin((band + miss) / r) of the line's direction or of its opposite. The
/// keypoints are kept in rings about the epipole, each twice as wide as the one inside it, each
/// by direction: a ring from `r` to `2r` is searched over the wedges its inner radius allows,
/// which hold about 1.5 times the keypoints of the band there, and only the few keypoints
/// within [`NEAR_PX`] of the epipole are tested always. The same exact test decides, so a query
/// returns the same keypoints as [`Grid::within_band`] (kitti-seq1's band queries walked about
/// 50 strips of cells each). Guided matching visits its keypoints in the order of their lines'
/// directions, so each ring keeps where the last query's two directions fell and walks out from
/// there. On kitti-seq1 a query tests 97 keypoints for the 66 inside its band; one disc of
/// `r0³ = b R² / 2π` (b = 4 px) and one pair of wedges tested 403, and the matches stage took
/// 2–4 % longer (the same matches).
pub(crate) struct Radial {
    e: [f64; 2],
    /// The keypoints within [`NEAR_PX`] of the epipole, with their positions.
    near: Vec<u32>,
    near_xy: Vec<[f64; 2]>,
    rings: Vec<Ring>,
}

/// The radius of [`Radial`]'s innermost disc, pixels.
const NEAR_PX: f64 = 8.0;

/// The keypoints from `r` to twice `r` from the epipole.
struct Ring {
    r: f64,
    /// Their directions from the epipole in (−π, π], ascending, with index and position.
    theta: Vec<f64>,
    index: Vec<u32>,
    xy: Vec<[f64; 2]>,
    /// Where the last query's two directions fell (a hint: any value is correct).
    hint: [std::cell::Cell<usize>; 2],
}

impl Ring {
    /// The first `k` at which `theta[k] ≥ t`, looked for from `hint` outwards (galloping, then
    /// bisecting): consecutive queries along the lines' directions move it a few places.
    fn seek(&self, t: f64, hint: &std::cell::Cell<usize>) -> usize {
        let n = self.theta.len();
        let mut k = hint.get().min(n);
        if k > 0 && self.theta[k - 1] >= t {
            let (mut step, mut hi) = (1, k);
            loop {
                let lo = hi.saturating_sub(step);
                if lo == 0 || self.theta[lo - 1] < t {
                    k = lo + self.theta[lo..hi].partition_point(|&v| v < t);
                    break;
                }
                hi = lo;
                step *= 2;
            }
        } else {
            let (mut step, mut lo) = (1, k);
            loop {
                let hi = (lo + step).min(n);
                if hi == n || self.theta[hi - 1] >= t {
                    k = lo + self.theta[lo..hi].partition_point(|&v| v < t);
                    break;
                }
                lo = hi;
                step *= 2;
            }
        }
        hint.set(k);
        k
    }

    /// Every keypoint of the ring within `w` of direction `c` (and perhaps a few more) to `visit`,
    /// walking out from `c` both ways, round the turn where the wedge wraps.
    fn wedge(&self, c: f64, w: f64, hint: &std::cell::Cell<usize>, mut visit: impl FnMut(usize)) {
        use std::f64::consts::TAU;
        let n = self.theta.len();
        if n == 0 {
            return;
        }
        let start = self.seek(c, hint);
        // Up from `c` (wrapping past +π to −π), then down from it, `n` places at most in all.
        let mut left = n;
        let mut i = start;
        while left > 0 {
            if i == n {
                i = 0;
            }
            let mut d = self.theta[i] - c;
            if d < 0.0 {
                d += TAU;
            }
            if d > w {
                break;
            }
            visit(i);
            i += 1;
            left -= 1;
        }
        let mut i = start;
        while left > 0 {
            i = if i == 0 { n - 1 } else { i - 1 };
            let mut d = c - self.theta[i];
            if d < 0.0 {
                d += TAU;
            }
            if d > w {
                break;
            }
            visit(i);
            left -= 1;
        }
    }
}

impl Radial {
    /// The keypoints of `f2` about the epipole of `f` in image 2; `None` where the epipole is at
    /// infinity, at least the keypoints' diagonal outside their bounding box ([`Pencil`]'s
    /// case, and far enough for the line's miss of the epipole to lose its precision), or the
    /// keypoints have no extent.
    pub(crate) fn new(f2: &Features, f: &nalgebra::Matrix3<f64>) -> Option<Self> {
        let e = epipole(f)?;
        let (lo, hi) = bounds(f2);
        let diag = ((hi[0] - lo[0]).powi(2) + (hi[1] - lo[1]).powi(2)).sqrt();
        let dx = (lo[0] - e[0]).max(e[0] - hi[0]).max(0.0);
        let dy = (lo[1] - e[1]).max(e[1] - hi[1]).max(0.0);
        if !(diag.is_finite() && diag > 0.0 && (dx * dx + dy * dy).sqrt() < diag) {
            return None;
        }
        let (mut near, mut near_xy) = (Vec::new(), Vec::new());
        let mut rings: Vec<Vec<(f64, u32, [f64; 2])>> = Vec::new();
        for (i, k) in f2.keypoints.iter().enumerate() {
            let (x, y) = (k.x as f64, k.y as f64);
            let (dx, dy) = (x - e[0], y - e[1]);
            let r = (dx * dx + dy * dy).sqrt();
            if r < NEAR_PX || !r.is_finite() {
                near.push(i as u32);
                near_xy.push([x, y]);
            } else {
                // Ring `q` holds r in [NEAR_PX·2^q, NEAR_PX·2^(q+1)).
                let mut q = (r / NEAR_PX).log2().floor().max(0.0) as usize;
                // Rounding of the logarithm: the ring's inner radius must not pass `r`.
                while q > 0 && NEAR_PX * (1u64 << q.min(62)) as f64 > r {
                    q -= 1;
                }
                if rings.len() <= q {
                    rings.resize_with(q + 1, Vec::new);
                }
                rings[q].push((dy.atan2(dx), i as u32, [x, y]));
            }
        }
        let rings = rings
            .into_iter()
            .enumerate()
            .filter(|(_, v)| !v.is_empty())
            .map(|(q, mut v)| {
                v.sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
                Ring {
                    r: NEAR_PX * (1u64 << q.min(62)) as f64,
                    theta: v.iter().map(|p| p.0).collect(),
                    index: v.iter().map(|p| p.1).collect(),
                    xy: v.iter().map(|p| p.2).collect(),
                    hint: Default::default(),
                }
            })
            .collect();
        Some(Self {
            e,
            near,
            near_xy,
            rings,
        })
    }

    /// [`Grid::within_band`]: the keypoints whose distance from `l` is at most `band` pixels,
    /// measured as the caller would; those near the epipole first, then ring by ring, each by
    /// direction.
    pub(crate) fn within_band(&self, l: &Vector3<f64>, band: f64, out: &mut Vec<u32>) {
        use std::f64::consts::PI;
        out.clear();
        let n = (l.x * l.x + l.y * l.y).sqrt();
        if n < 1e-300 {
            return;
        }
        let test = BandTest::new(l, band);
        for (k, &[x, y]) in self.near_xy.iter().enumerate() {
            if test.holds(x, y) {
                out.push(self.near[k]);
            }
        }
        // `l` passes within `miss` of the epipole (F's rank 2 in exact arithmetic only).
        let miss = ((l.x * self.e[0] + l.y * self.e[1] + l.z) / n).abs();
        let phi = (-l.x / n).atan2(l.y / n);
        let opposite = if phi > 0.0 { phi - PI } else { phi + PI };
        // The line's two directions, the one in [0, π) first: each keeps its own hint whichever
        // way `l` is signed.
        let (up, down) = if (0.0..PI).contains(&phi) {
            (phi, opposite)
        } else {
            (opposite, phi)
        };
        let mut visit = |ring: &Ring, k: usize| {
            let [x, y] = ring.xy[k];
            if test.holds(x, y) {
                out.push(ring.index[k]);
            }
        };
        // The wedge of the innermost ring that has one, `w0` at `r0`; each ring out, that scaled
        // by `r0 / r` (asin is convex from 0, so asin(λ s) ≤ λ asin(s): never narrower than its
        // own, and one arc sine a query).
        let (mut w0, mut r0) = (f64::NAN, 0.0);
        for ring in &self.rings {
            let s = (band + miss) / ring.r;
            if s.is_nan() || s >= 0.5 {
                for k in 0..ring.xy.len() {
                    visit(ring, k);
                }
                continue;
            }
            // Widened against rounding: the exact test decides.
            if w0.is_nan() {
                (w0, r0) = (s.asin() * (1.0 + 1e-6) + 1e-12, ring.r);
            }
            let w = w0 * (r0 / ring.r) * (1.0 + 1e-9);
            for (c, hint) in [(up, &ring.hint[0]), (down, &ring.hint[1])] {
                ring.wedge(c, w, hint, |k| visit(ring, k));
            }
        }
    }
}

/// The epipole in image 2 of `f` (`Fᵀ`'s null vector: orthogonal to every column of `F`), or
/// `None` at infinity.
fn epipole(f: &nalgebra::Matrix3<f64>) -> Option<[f64; 2]> {
    let cols = [
        f.column(0).into_owned(),
        f.column(1).into_owned(),
        f.column(2).into_owned(),
    ];
    let e = [(0, 1), (0, 2), (1, 2)]
        .iter()
        .map(|&(a, b)| cols[a].cross(&cols[b]))
        .max_by(|a, b| a.norm_squared().total_cmp(&b.norm_squared()))?;
    (e.z != 0.0).then(|| [e.x / e.z, e.y / e.z])
}

/// The keypoints' bounding box, `(lo, hi)`.
pub(crate) fn bounds(f: &Features) -> ([f64; 2], [f64; 2]) {
    f.keypoints.iter().fold(
        ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]),
        |(lo, hi), k| {
            let (x, y) = (k.x as f64, k.y as f64);
            ([lo[0].min(x), lo[1].min(y)], [hi[0].max(x), hi[1].max(y)])
        },
    )
}

#[cfg(test)]
#[path = "epipolar_grid_tests.rs"]
mod tests;
