use super::*;
use crate::detector::Keypoint;

/// A seeded generator of uniform values in [0, 1) (a 64-bit LCG, the upper bits).
fn generator(seed: u64) -> impl FnMut() -> f64 {
    let mut s = seed;
    move || {
        s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (s >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// `n` keypoints spread uniformly over 1000 × 700 px.
fn scattered(n: usize, rnd: &mut impl FnMut() -> f64) -> Features {
    let keypoints: Vec<Keypoint> = (0..n)
        .map(|_| Keypoint {
            x: (rnd() * 1000.0) as f32,
            y: (rnd() * 700.0) as f32,
            scale: 1.0,
            orientation: 0.0,
            response: 1.0,
        })
        .collect();
    Features {
        keypoints,
        descriptors: Default::default(),
    }
}

#[test]
fn grid_band_query_finds_every_keypoint_near_the_line() {
    let mut rnd = generator(12345);
    let f = scattered(3000, &mut rnd);
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

#[test]
fn the_pencil_finds_exactly_the_keypoints_the_grid_does() {
    let mut rnd = generator(99);
    let f = scattered(4000, &mut rnd);
    let grid = Grid::new(&f, 32.0);
    let (mut a, mut b) = (Vec::new(), Vec::new());
    let mut used = 0;
    for _ in 0..50 {
        // A rank-2 F whose epipole in image 2 is e (right null vector of Fᵀ): F = [e]ₓ M.
        let e = Vector3::new(
            500.0 + (rnd() - 0.5) * 20000.0,
            350.0 + (rnd() - 0.5) * 20000.0,
            1.0,
        );
        let ex = nalgebra::Matrix3::new(0.0, -e.z, e.y, e.z, 0.0, -e.x, -e.y, e.x, 0.0);
        let m = nalgebra::Matrix3::from_fn(|_, _| rnd() - 0.5);
        let fm = ex * m;
        let Some(pencil) = Pencil::new(&f, &fm) else {
            continue;
        };
        used += 1;
        for _ in 0..100 {
            let x1 = Vector3::new(rnd() * 1000.0, rnd() * 700.0, 1.0);
            let l = fm * x1;
            grid.within_band(&l, 2.0, &mut a);
            pencil.within_band(&l, 2.0, &mut b);
            a.sort_unstable();
            b.sort_unstable();
            assert_eq!(a, b);
        }
    }
    assert!(used > 10, "only {used} epipoles far enough");
}

#[test]
fn the_radial_pencil_finds_exactly_the_keypoints_the_grid_does() {
    let mut rnd = generator(7);
    let f = scattered(4000, &mut rnd);
    let grid = Grid::new(&f, 32.0);
    let (mut a, mut b) = (Vec::new(), Vec::new());
    for trial in 0..60 {
        // Epipoles inside the keypoints' extent, near it, and on a keypoint.
        let e = if trial == 0 {
            let k = &f.keypoints[17];
            Vector3::new(k.x as f64, k.y as f64, 1.0)
        } else {
            Vector3::new(
                500.0 + (rnd() - 0.5) * 1600.0,
                350.0 + (rnd() - 0.5) * 1200.0,
                1.0,
            )
        };
        let ex = nalgebra::Matrix3::new(0.0, -e.z, e.y, e.z, 0.0, -e.x, -e.y, e.x, 0.0);
        let m = nalgebra::Matrix3::from_fn(|_, _| rnd() - 0.5);
        let fm = ex * m;
        let radial = Radial::new(&f, &fm).expect("a finite epipole");
        for band in [2.0, 7.5] {
            for _ in 0..60 {
                let x1 = Vector3::new(rnd() * 1000.0, rnd() * 700.0, 1.0);
                let l = fm * x1;
                grid.within_band(&l, band, &mut a);
                radial.within_band(&l, band, &mut b);
                a.sort_unstable();
                b.sort_unstable();
                assert_eq!(a, b, "epipole {e:?}, band {band}");
            }
        }
    }
}
