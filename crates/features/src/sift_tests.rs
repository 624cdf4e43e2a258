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
fn upsampling_equals_bilinear_sampling_bit_for_bit() {
    for (w, h) in [(1, 1), (1, 3), (2, 1), (37, 23), (64, 5)] {
        let img = GrayImage {
            width: w,
            height: h,
            data: (0..w * h)
                .map(|i| ((i * 7919) % 97) as f32 / 97.0 + 0.013)
                .collect(),
        };
        let up = upsample2(&img);
        assert_eq!((up.width, up.height), (2 * w, 2 * h));
        for y in 0..2 * h {
            let sy = (y as f32 + 0.5) * 0.5 - 0.5;
            for x in 0..2 * w {
                let want = img.sample((x as f32 + 0.5) * 0.5 - 0.5, sy);
                assert_eq!(
                    up.data[y * 2 * w + x].to_bits(),
                    want.to_bits(),
                    "{w}x{h} at ({x}, {y})"
                );
            }
        }
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
