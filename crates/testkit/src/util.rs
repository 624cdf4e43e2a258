//! Small deterministic helpers shared by the generators: integer hashing for the procedural texture
//! (so a texel is a pure function of its cell, never of evaluation order), Gaussian samples from a
//! seeded [`ChaCha8Rng`], and a look-at rotation in Handheld's camera convention (x right, y down,
//! z forward).

use nalgebra::{Matrix3, Point3, Rotation3, Vector3};
use rand::Rng;
use rand_chacha::ChaCha8Rng;

/// The SplitMix64 finaliser: a fast bijective mixer with good avalanche.
#[inline]
pub fn mix64(mut x: u64) -> u64 {
    x = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^ (x >> 31)
}

/// Hash of a list of words (order-sensitive).
pub fn hash_words(words: &[u64]) -> u64 {
    words
        .iter()
        .fold(0x51_7CC1_B727_220A_u64, |h, &w| mix64(h ^ w))
}

/// A one-round hash of an integer cell `(i, j)` of layer `layer` under `seed` (for the texture's inner
/// loop, where [`hash_words`] would be needlessly slow).
#[inline]
pub fn hash_cell(seed: u64, layer: u64, i: i64, j: i64) -> u64 {
    mix64(
        seed ^ (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
            ^ (j as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
            ^ layer.wrapping_mul(0x1656_67B1_9E37_79F9).rotate_left(17),
    )
}

/// Maps a hash to `[0, 1)` using its top 53 bits.
#[inline]
pub fn unit_from_hash(h: u64) -> f64 {
    (h >> 11) as i64 as f64 * (1.0 / (1u64 << 53) as f64)
}

/// A standard normal sample (Box–Muller; one of the pair is discarded for simplicity).
pub fn gaussian(rng: &mut ChaCha8Rng) -> f64 {
    let u1: f64 = 1.0 - rng.random::<f64>(); // (0, 1]
    let u2: f64 = rng.random::<f64>();
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

/// A 3-vector of independent normal samples with standard deviation `sigma`.
pub fn gaussian_vec3(rng: &mut ChaCha8Rng, sigma: f64) -> Vector3<f64> {
    Vector3::new(gaussian(rng), gaussian(rng), gaussian(rng)) * sigma
}

/// `world_from_cam` rotation of a camera at `eye` looking at `target`, with world `up` projecting
/// upwards in the image (camera y points down). `None` when the view direction is degenerate
/// (zero or parallel to `up`).
pub fn look_at(
    eye: &Point3<f64>,
    target: &Point3<f64>,
    up: &Vector3<f64>,
) -> Option<Rotation3<f64>> {
    let z = (target - eye).try_normalize(1e-12)?;
    let x = z.cross(up).try_normalize(1e-9)?;
    let y = z.cross(&x);
    Some(Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[
        x, y, z,
    ])))
}

/// A rotation by a small axis-angle vector (radians).
pub fn small_rotation(omega: &Vector3<f64>) -> Rotation3<f64> {
    Rotation3::new(*omega)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn look_at_puts_target_on_axis_and_up_upwards() {
        let eye = Point3::new(1.0, -4.0, 1.5);
        let target = Point3::new(0.0, 0.0, 0.3);
        let r = look_at(&eye, &target, &Vector3::z()).expect("non-degenerate");
        let dir_cam = r.inverse() * (target - eye);
        assert!(dir_cam.x.abs() < 1e-12 && dir_cam.y.abs() < 1e-12 && dir_cam.z > 0.0);
        // World up maps to negative camera y (image up).
        assert!((r.inverse() * Vector3::z()).y < 0.0);
        assert!((r.matrix().determinant() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn gaussian_has_unit_variance() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let s: Vec<f64> = (0..20000).map(|_| gaussian(&mut rng)).collect();
        let mean = s.iter().sum::<f64>() / s.len() as f64;
        let var = s.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / s.len() as f64;
        assert!(
            mean.abs() < 0.03 && (var - 1.0).abs() < 0.05,
            "mean {mean} var {var}"
        );
    }

    #[test]
    fn unit_from_hash_is_in_range() {
        for i in 0..1000u64 {
            let u = unit_from_hash(hash_words(&[i, 7]));
            assert!((0.0..1.0).contains(&u));
        }
    }
}
