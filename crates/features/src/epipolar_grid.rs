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
struct Layout {
    start: Vec<u32>,
    index: Vec<u32>,
    /// The position of `index[k]`, in the same order (the band test reads them in sequence).
    xy: Vec<[f64; 2]>,
}

impl Layout {
    fn new(
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
        let n = (l.x * l.x + l.y * l.y).sqrt();
        self.walk(l, band, |layout, range| {
            for k in range {
                let [x, y] = layout.xy[k];
                if ((l.x * x + l.y * y + l.z) / n).abs() <= band {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::detector::Keypoint;

    #[test]
    fn grid_band_query_finds_every_keypoint_near_the_line() {
        let mut s = 12345u64;
        let mut rnd = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 11) as f64 / (1u64 << 53) as f64
        };
        let keypoints: Vec<Keypoint> = (0..3000)
            .map(|_| Keypoint {
                x: (rnd() * 1000.0) as f32,
                y: (rnd() * 700.0) as f32,
                scale: 1.0,
                orientation: 0.0,
                response: 1.0,
            })
            .collect();
        let f = Features {
            keypoints,
            descriptors: Default::default(),
        };
        let grid = Grid::new(&f, 32.0);
        let mut out = Vec::new();
        for _ in 0..200 {
            let th = rnd() * std::f64::consts::PI;
            let (a, b) = (th.cos(), th.sin());
            let c = -(a * rnd() * 1000.0 + b * rnd() * 700.0);
            let l = Vector3::new(a, b, c) * (1.0 + 10.0 * rnd());
            grid.near_line(&l, 2.0, &mut out);
            let n = (l.x * l.x + l.y * l.y).sqrt();
            for (k, p) in f.keypoints.iter().enumerate() {
                if ((l.x * p.x as f64 + l.y * p.y as f64 + l.z) / n).abs() <= 2.0 {
                    assert!(out.contains(&(k as u32)), "keypoint {k} missed");
                }
            }
            assert!(
                out.len() < f.keypoints.len() / 2,
                "the band query should prune"
            );
        }
    }
}
