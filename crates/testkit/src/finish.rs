//! Surface finishes of the synthetic scene's primitives ([`crate::Scene::with_finish`]): the rich
//! block texture, plain paint, or floor tiles, each drawn from the primitive's
//! [`crate::texture::FaceTexture`].

use nalgebra::Vector2;
use serde::{Deserialize, Serialize};

use crate::texture::FaceTexture;

/// How a primitive's albedo is drawn from its procedural texture: the rich block texture, or the
/// surfaces of a building's interior that give a tracker little (plain paint, a tiled floor).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub enum Finish {
    /// The multi-scale block texture with its landmarks ([`crate::texture`]).
    #[default]
    Textured,
    /// Paint: the block texture's contrast scaled by `contrast` (about 0.05–0.15) around a light
    /// grey, so that only faint blotches are left; no landmark disks are drawn.
    Plain { contrast: f64 },
    /// Square tiles of side `size` metres, each a nearly uniform shade (a faint copy of the
    /// texture), separated by dark grout lines 1 cm wide: a repeated pattern.
    Tiles { size: f64 },
    /// Printed wallpaper: one motif of the block texture, `period` metres square, repeated on a
    /// lattice whose every other row is shifted by half a period (a half-drop match). Every corner
    /// has copies a period away that look the same: the ambiguity a real pattern gives a matcher.
    Wallpaper { period: f64 },
}

impl Finish {
    /// The RGB albedo at surface coordinates `uv` (metres) of a face textured by `t`.
    pub fn albedo(&self, t: &FaceTexture, uv: &Vector2<f64>) -> [f64; 3] {
        match *self {
            Finish::Textured => t.albedo(uv),
            Finish::Plain { contrast } => faint(t.blocks(uv), 0.72, contrast),
            Finish::Tiles { size } => {
                let s = size.max(0.02);
                let (fu, fv) = ((uv.x / s).fract(), (uv.y / s).fract());
                let grout = 0.005 / s;
                if fu < grout || fu > 1.0 - grout || fv < grout || fv > 1.0 - grout {
                    return [0.22, 0.21, 0.2];
                }
                // One shade per tile, from the texture at the tile's centre.
                let centre = Vector2::new(
                    ((uv.x / s).floor() + 0.5) * s,
                    ((uv.y / s).floor() + 0.5) * s,
                );
                let shade = faint(t.albedo(&centre), 0.6, 0.08);
                let grain = faint(t.blocks(uv), 0.0, 0.05);
                [0, 1, 2].map(|c| (shade[c] + grain[c]).clamp(0.0, 1.0))
            }
            Finish::Wallpaper { period } => {
                let p = period.max(0.02);
                let row = (uv.y / p).floor();
                let shift = if row.rem_euclid(2.0) == 1.0 {
                    0.5 * p
                } else {
                    0.0
                };
                let motif = Vector2::new((uv.x + shift).rem_euclid(p), uv.y - row * p);
                t.blocks(&motif)
            }
        }
    }
}

/// `rgb` pulled towards `base`, keeping `contrast` of its deviation from mid-grey.
fn faint(rgb: [f64; 3], base: f64, contrast: f64) -> [f64; 3] {
    rgb.map(|c| base + contrast * (c - 0.5))
}
