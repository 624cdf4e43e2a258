//! Procedural surface texture with corners at every scale, evaluated analytically at a surface point.
//!
//! Every textured face (a rectangle of a plane or box, or the latitude/longitude chart of a sphere)
//! carries 2D surface coordinates `uv` in metres. The albedo at `uv` is
//!
//! * a sum of six octaves of random axis-aligned blocks (cell sizes 64 cm down to 2 cm, each octave
//!   shifted by a random offset so that edges of different octaves do not line up), clamped to a
//!   high-contrast grey range and tinted by a random colour per 1.28 m cell — block corners give
//!   trackable corners from far away and from close up alike;
//! * on rectangular faces, a sparse set of **landmarks**: a dark disk of radius
//!   [`LANDMARK_RADIUS`] centred in a uniformly bright square of half-size [`LANDMARK_HALF_SQUARE`].
//!   The face is tiled by landmark cells of about [`LANDMARK_CELL`] metres; each cell holds a
//!   landmark with probability [`LANDMARK_PROBABILITY`] at a random position chosen so its square lies
//!   inside the cell. The disk centres are known exactly in 3D (see `Scene::landmarks`) and are the
//!   ground-truth feature points of the synthetic sequences.
//!
//! Everything is a pure function of `(seed, uv)`, so the texture is identical across views and runs.
//! For speed, block lookups quantise `uv` to 0.3125 mm and hash integer cells (one mixing round per
//! octave); landmark disks and squares are tested on the exact `uv`.

use nalgebra::Vector2;

use crate::util::{hash_cell, hash_words, unit_from_hash};

/// Nominal landmark cell size in metres (faces are tiled by a whole number of cells close to this).
pub const LANDMARK_CELL: f64 = 0.5;
/// Radius of a landmark's dark disk in metres.
pub const LANDMARK_RADIUS: f64 = 0.04;
/// Half the side of the bright square around a landmark disk, in metres.
pub const LANDMARK_HALF_SQUARE: f64 = 0.14;
/// Probability that a landmark cell holds a landmark.
pub const LANDMARK_PROBABILITY: f64 = 0.5;
/// Minimum distance between a landmark square and its cell border, in metres.
const LANDMARK_GAP: f64 = 0.02;
/// Albedo of a landmark disk.
pub const LANDMARK_DARK: f64 = 0.06;
/// Albedo of the square around a landmark disk.
pub const LANDMARK_BRIGHT: f64 = 0.92;

/// Surface coordinates are quantised to this step (metres) before the block lookup, so that every
/// octave's cell index is an integer shift: octave `o` has cells of `2^(11−o)` quanta (64 cm … 2 cm).
const QUANTUM: f64 = 0.02 / 64.0;
const OCTAVE_SHIFTS: [u32; 6] = [11, 10, 9, 8, 7, 6];
const OCTAVE_AMPLITUDES: [f64; 6] = [0.55, 0.5, 0.45, 0.4, 0.35, 0.3];
/// Tint cells are `2^12` quanta (1.28 m).
const TINT_SHIFT: u32 = 12;

/// The texture of one face: its seed, extent and landmark tiling.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FaceTexture {
    /// Seed of this face (derived from the primitive's texture id and the face index).
    pub seed: u64,
    /// Extent of the face in metres along `u` and `v`.
    pub size: Vector2<f64>,
    /// Number of landmark cells along `u` and `v`; zero when the face carries no landmarks.
    pub cells: [u32; 2],
    /// Landmark cell size in metres along `u` and `v`.
    pub cell_size: Vector2<f64>,
    /// Offsets (in quanta) of each octave's block grid, precomputed from the seed.
    offsets: [[i64; 2]; 6],
    inv_cell_size: Vector2<f64>,
}

impl FaceTexture {
    /// The texture of face `face` of a primitive with texture id `texture` and extent `size` (metres);
    /// `landmarks` enables the landmark tiling (rectangular faces only).
    pub fn new(texture: u64, face: u32, size: Vector2<f64>, landmarks: bool) -> Self {
        let seed = hash_words(&[texture, face as u64, 0xFACE]);
        let mut offsets = [[0i64; 2]; 6];
        for (o, off) in offsets.iter_mut().enumerate() {
            for (a, v) in off.iter_mut().enumerate() {
                *v = (hash_words(&[seed, 100 + o as u64, a as u64]) % (1u64 << OCTAVE_SHIFTS[o]))
                    as i64;
            }
        }
        let min_cell = 2.0 * (LANDMARK_HALF_SQUARE + LANDMARK_GAP);
        let mut cells = [0u32; 2];
        let mut cell_size = Vector2::new(LANDMARK_CELL, LANDMARK_CELL);
        if landmarks {
            for a in 0..2 {
                let n = (size[a] / LANDMARK_CELL).round().max(1.0);
                let c = size[a] / n;
                if c >= min_cell && n.is_finite() {
                    cells[a] = n as u32;
                    cell_size[a] = c;
                }
            }
            if cells[0] == 0 || cells[1] == 0 {
                cells = [0, 0];
            }
        }
        Self {
            seed,
            size,
            cells,
            cell_size,
            offsets,
            inv_cell_size: cell_size.map(|c| 1.0 / c),
        }
    }

    /// The landmark centre of cell `(i, j)`, if that cell holds one.
    pub fn landmark_in_cell(&self, i: u32, j: u32) -> Option<Vector2<f64>> {
        if i >= self.cells[0] || j >= self.cells[1] {
            return None;
        }
        let h = hash_cell(self.seed, 0x1A4D, i as i64, j as i64);
        if unit_from_hash(h) >= LANDMARK_PROBABILITY {
            return None;
        }
        let h2 = crate::util::mix64(h);
        let mut c = Vector2::zeros();
        for a in 0..2 {
            let range = self.cell_size[a] - 2.0 * (LANDMARK_HALF_SQUARE + LANDMARK_GAP);
            // 26 independent bits per axis.
            let r = ((h2 >> (32 * a)) & 0x3FF_FFFF) as f64 / (1u64 << 26) as f64;
            let idx = if a == 0 { i } else { j } as f64;
            c[a] = idx * self.cell_size[a] + LANDMARK_HALF_SQUARE + LANDMARK_GAP + r * range;
        }
        Some(c)
    }

    /// Every landmark centre of the face, in cell order.
    pub fn landmarks(&self) -> Vec<Vector2<f64>> {
        let mut out = Vec::new();
        for j in 0..self.cells[1] {
            for i in 0..self.cells[0] {
                if let Some(c) = self.landmark_in_cell(i, j) {
                    out.push(c);
                }
            }
        }
        out
    }

    /// The landmark whose cell contains `uv`, if any.
    #[inline]
    fn landmark_near(&self, uv: &Vector2<f64>) -> Option<Vector2<f64>> {
        if self.cells[0] == 0 {
            return None;
        }
        let i = (uv.x * self.inv_cell_size.x)
            .floor()
            .clamp(0.0, (self.cells[0] - 1) as f64) as u32;
        let j = (uv.y * self.inv_cell_size.y)
            .floor()
            .clamp(0.0, (self.cells[1] - 1) as f64) as u32;
        self.landmark_in_cell(i, j)
    }

    /// RGB albedo in `[0, 1]` at surface coordinates `uv` (metres).
    pub fn albedo(&self, uv: &Vector2<f64>) -> [f64; 3] {
        if let Some(c) = self.landmark_near(uv) {
            let d = uv - c;
            if d.x.abs() < LANDMARK_HALF_SQUARE && d.y.abs() < LANDMARK_HALF_SQUARE {
                let g = if d.norm_squared() < LANDMARK_RADIUS * LANDMARK_RADIUS {
                    LANDMARK_DARK
                } else {
                    LANDMARK_BRIGHT
                };
                return [g, g, g];
            }
        }
        self.blocks(uv)
    }

    /// The RGB albedo of the block texture alone at `uv`, without the landmarks.
    pub fn blocks(&self, uv: &Vector2<f64>) -> [f64; 3] {
        let qu = (uv.x * (1.0 / QUANTUM)).floor() as i64;
        let qv = (uv.y * (1.0 / QUANTUM)).floor() as i64;
        let mut g = 0.5;
        for o in 0..OCTAVE_SHIFTS.len() {
            let i = (qu + self.offsets[o][0]) >> OCTAVE_SHIFTS[o];
            let j = (qv + self.offsets[o][1]) >> OCTAVE_SHIFTS[o];
            g +=
                OCTAVE_AMPLITUDES[o] * (unit_from_hash(hash_cell(self.seed, o as u64, i, j)) - 0.5);
        }
        let g = g.clamp(0.04, 0.96);
        let th = hash_cell(self.seed, 0x7147, qu >> TINT_SHIFT, qv >> TINT_SHIFT);
        let mut rgb = [g; 3];
        for (k, c) in rgb.iter_mut().enumerate() {
            *c *= 0.55
                + 0.45 * ((th >> (21 * k)) & 0x1F_FFFF) as i64 as f64 * (1.0 / (1u64 << 21) as f64);
        }
        rgb
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn landmark_squares_stay_inside_their_cells_and_face() {
        let t = FaceTexture::new(42, 3, Vector2::new(6.0, 2.5), true);
        assert_eq!(t.cells, [12, 5]);
        let lms = t.landmarks();
        assert!(lms.len() > 10, "{} landmarks", lms.len());
        for c in &lms {
            for a in 0..2 {
                assert!(
                    c[a] - LANDMARK_HALF_SQUARE >= 0.0 && c[a] + LANDMARK_HALF_SQUARE <= t.size[a]
                );
            }
            assert_eq!(t.albedo(c), [LANDMARK_DARK; 3]);
            let edge = c + Vector2::new(LANDMARK_HALF_SQUARE * 0.9, 0.0);
            assert_eq!(t.albedo(&edge), [LANDMARK_BRIGHT; 3]);
        }
    }

    #[test]
    fn small_faces_have_no_landmarks_and_texture_is_deterministic() {
        let t = FaceTexture::new(1, 0, Vector2::new(0.2, 2.0), true);
        assert!(t.landmarks().is_empty());
        let a = FaceTexture::new(9, 1, Vector2::new(3.0, 3.0), false);
        let b = FaceTexture::new(9, 1, Vector2::new(3.0, 3.0), false);
        let c = FaceTexture::new(10, 1, Vector2::new(3.0, 3.0), false);
        let uv = Vector2::new(1.234, 0.567);
        assert_eq!(a.albedo(&uv), b.albedo(&uv));
        let differs = (0..50).any(|k| {
            let p = Vector2::new(0.05 * k as f64, 0.03 * k as f64);
            a.albedo(&p) != c.albedo(&p)
        });
        assert!(differs);
    }

    #[test]
    fn texture_has_contrast_at_fine_scale() {
        let t = FaceTexture::new(5, 0, Vector2::new(2.0, 2.0), false);
        // Along a 10 cm segment the finest octave (2 cm) must produce several distinct values.
        let mut vals: Vec<f64> = (0..100)
            .map(|k| t.albedo(&Vector2::new(0.7 + 0.001 * k as f64, 0.9))[0])
            .collect();
        vals.dedup();
        assert!(vals.len() >= 4, "{vals:?}");
    }
}
