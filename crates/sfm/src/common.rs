//! Small helpers that several phases share, in a leaf that imports nothing of the crate: the
//! median of a sample, and the image centre, where the principal point's prior puts it (eq. 25's
//! `u ≈ v ≈ 0` in `K_N` units).

/// The median of `v` (the upper one of an even count; NaN when empty), sorting `v` in place.
pub(crate) fn median(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// The image centre in Handheld's pixel convention: the principal point's prior mean.
pub(crate) fn image_centre(width: u32, height: u32) -> nalgebra::Vector2<f64> {
    nalgebra::Vector2::new((width as f64 - 1.0) / 2.0, (height as f64 - 1.0) / 2.0)
}
