//! Hartley's isotropic normalisation (H&Z §4.4.4, "Normalizing transformations"; Hartley 1997, "In
//! defense of the eight-point algorithm"). Every linear solver in this crate conditions its design
//! matrix this way, so the transform lives in its own file.

use nalgebra::{Matrix3, Vector2};

use crate::error::{GeometryError, Result};

/// The similarity `T` and the normalised points `T x` (inhomogeneous).
#[derive(Clone, Debug, PartialEq)]
pub struct Normalization {
    /// `T = [[s, 0, −s·cx], [0, s, −s·cy], [0, 0, 1]]`.
    pub t: Matrix3<f64>,
    /// The normalised points, centroid at the origin and mean distance `√2` from it.
    pub points: Vec<Vector2<f64>>,
}

impl Normalization {
    /// Scale factor `s` of the transform.
    pub fn scale(&self) -> f64 {
        self.t[(0, 0)]
    }
}

/// Translates the points to their centroid and scales them so that their mean distance from the
/// origin is `√2` (H&Z alg. 4.2, step (i)).
///
/// Errors: no points, a non-finite coordinate, or all points coincident (the scale is undefined).
pub fn hartley_normalization(points: &[Vector2<f64>]) -> Result<Normalization> {
    if points.is_empty() {
        return Err(GeometryError::InsufficientCorrespondences {
            required: 1,
            actual: 0,
        });
    }
    if points.iter().any(|p| !p.x.is_finite() || !p.y.is_finite()) {
        return Err(GeometryError::NonFinite);
    }
    let n = points.len() as f64;
    let centroid = points.iter().sum::<Vector2<f64>>() / n;
    let mean_dist = points.iter().map(|p| (p - centroid).norm()).sum::<f64>() / n;
    // Relative test so that pixel-scale and unit-scale inputs are treated alike.
    let extent = centroid.abs().max() + mean_dist;
    if mean_dist.is_nan() || mean_dist <= 1e-12 * extent {
        return Err(GeometryError::Degenerate {
            reason: "all points coincide",
        });
    }
    let s = std::f64::consts::SQRT_2 / mean_dist;
    let t = Matrix3::new(
        s,
        0.0,
        -s * centroid.x,
        0.0,
        s,
        -s * centroid.y,
        0.0,
        0.0,
        1.0,
    );
    let normalised = points.iter().map(|p| (p - centroid) * s).collect();
    Ok(Normalization {
        t,
        points: normalised,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn centroid_zero_and_mean_distance_sqrt2() {
        let pts = vec![
            Vector2::new(10.0, 20.0),
            Vector2::new(400.0, 25.0),
            Vector2::new(320.0, 470.0),
            Vector2::new(33.0, 300.0),
            Vector2::new(250.0, 250.0),
        ];
        let nrm = hartley_normalization(&pts).expect("well-posed");
        let c: Vector2<f64> = nrm.points.iter().sum::<Vector2<f64>>() / 5.0;
        assert!(c.norm() < 1e-12);
        let mean = nrm.points.iter().map(|p| p.norm()).sum::<f64>() / 5.0;
        assert!((mean - std::f64::consts::SQRT_2).abs() < 1e-12);
        for (p, q) in pts.iter().zip(&nrm.points) {
            let th = nrm.t * p.push(1.0);
            assert!((th.xy() / th.z - q).norm() < 1e-12);
        }
    }

    #[test]
    fn degenerate_inputs_are_errors() {
        assert!(hartley_normalization(&[]).is_err());
        let same = vec![Vector2::new(3.0, 4.0); 6];
        assert!(matches!(
            hartley_normalization(&same),
            Err(GeometryError::Degenerate { .. })
        ));
        let nan = vec![Vector2::new(f64::NAN, 4.0), Vector2::new(1.0, 2.0)];
        assert_eq!(hartley_normalization(&nan), Err(GeometryError::NonFinite));
    }
}
