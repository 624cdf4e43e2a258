use super::*;
use std::f32::consts::PI;

#[test]
fn fast_atan2_is_accurate() {
    for i in 0..720 {
        let a = i as f32 * PI / 360.0 + 0.001;
        let (s, c) = a.sin_cos();
        let got = fast_atan2(3.0 * s, 3.0 * c);
        let want = a.rem_euclid(2.0 * PI);
        let err = (got - want).abs().min(2.0 * PI - (got - want).abs());
        assert!(err < 2e-4, "angle {a}: {got} vs {want}");
    }
}

#[test]
fn blur_matches_reference() {
    let img = GrayImage {
        width: 37,
        height: 23,
        data: (0..37 * 23)
            .map(|i| ((i * 7919) % 97) as f32 / 97.0)
            .collect(),
    };
    let want = img.gaussian_blur(1.7);
    let got = blur(&img.data, 37, 23, 1.7);
    for (a, b) in got.iter().zip(&want.data) {
        assert!((a - b).abs() < 1e-5);
    }
}
