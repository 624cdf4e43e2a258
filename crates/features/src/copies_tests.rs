use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::*;
use crate::detector::{Descriptors, Keypoint};

/// Wall points of a motif repeated over a 10 × 14 lattice of unit periods: five keypoints per
/// period at fixed offsets, each offset with its own descriptor, every copy with a little noise.
struct Wall {
    uv: Vec<Vector2<f64>>,
    motif: Vec<usize>,
    cell: Vec<(i32, i32)>,
}

const OFFSETS: [(f64, f64); 5] = [
    (0.1, 0.2),
    (0.45, 0.15),
    (0.8, 0.4),
    (0.3, 0.7),
    (0.65, 0.85),
];

fn wall() -> Wall {
    let mut w = Wall {
        uv: Vec::new(),
        motif: Vec::new(),
        cell: Vec::new(),
    };
    for i in 0..10 {
        for j in 0..14 {
            for (k, (du, dv)) in OFFSETS.iter().enumerate() {
                w.uv.push(Vector2::new(i as f64 + du, j as f64 + dv));
                w.motif.push(k);
                w.cell.push((i, j));
            }
        }
    }
    w
}

/// Image points `h · (u, v, 1)` with descriptors: the motif's (or, with `motif: None`, each
/// point's own random one) plus noise.
fn features(
    h: &Matrix3<f64>,
    uv: &[Vector2<f64>],
    motif: Option<&[usize]>,
    rng: &mut ChaCha8Rng,
) -> Features {
    const DIM: usize = 16;
    let mut base = ChaCha8Rng::seed_from_u64(99);
    let prototypes: Vec<Vec<f32>> = (0..OFFSETS.len())
        .map(|_| (0..DIM).map(|_| base.random::<f32>()).collect())
        .collect();
    let mut keypoints = Vec::new();
    let mut data = Vec::new();
    for (i, x) in uv.iter().enumerate() {
        let p = apply(h, *x).expect("a finite point");
        keypoints.push(Keypoint {
            x: p.x as f32,
            y: p.y as f32,
            scale: 2.0,
            orientation: 0.0,
            response: 1.0,
        });
        match motif {
            Some(m) => data.extend(
                prototypes[m[i]]
                    .iter()
                    .map(|v| v + 0.02 * rng.random::<f32>()),
            ),
            None => data.extend((0..DIM).map(|_| rng.random::<f32>())),
        }
    }
    Features {
        keypoints,
        descriptors: Descriptors { dim: DIM, data },
    }
}

/// The wall seen by two cameras: wall units to pixels, 60 px a period, with some perspective.
fn views() -> (Matrix3<f64>, Matrix3<f64>) {
    let h1 = Matrix3::new(60.0, 4.0, 40.0, -3.0, 58.0, 30.0, 1e-3, 5e-4, 1.0);
    let h2 = Matrix3::new(52.0, -6.0, 90.0, 5.0, 61.0, 20.0, -8e-4, 1e-3, 1.0);
    (h1, h2)
}

#[test]
fn a_pair_matched_half_to_the_patterns_copies_is_flagged() {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let w = wall();
    let (h1, h2) = views();
    let f1 = features(&h1, &w.uv, Some(&w.motif), &mut rng);
    let f2 = features(&h2, &w.uv, Some(&w.motif), &mut rng);
    // The left half matched right, the right half to the copy one period along u.
    let index = |i: i32, j: i32, k: usize| ((i * 14 + j) as usize) * OFFSETS.len() + k;
    let inliers: Vec<(u32, u32)> = (0..w.uv.len())
        .filter_map(|a| {
            let (i, j) = w.cell[a];
            match i {
                0..=4 => Some((a as u32, a as u32)),
                5..=8 => Some((a as u32, index(i + 1, j, w.motif[a]) as u32)),
                _ => None,
            }
        })
        .collect();
    let found = repeated_pattern(&f1, &f2, &inliers, 4.0, &RansacOptions::default());
    let c = found.expect("the copies are found");
    assert!(
        c.hits >= MIN_HITS && c.hits > 10 * c.control_hits.max(1),
        "{c:?}"
    );
}

#[test]
fn a_wall_and_a_real_second_plane_are_not_flagged() {
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    let w = wall();
    let (h1, h2) = views();
    // The same repeated wall, every match right, and a box face in front of it: its own
    // (non-repeating) texture over the middle of image 1, seen in image 2 through another
    // homography (parallax).
    let face: Vec<Vector2<f64>> = (0..300)
        .map(|_| {
            Vector2::new(
                3.0 + 4.0 * rng.random::<f64>(),
                4.0 + 6.0 * rng.random::<f64>(),
            )
        })
        .collect();
    let mut uv = w.uv.clone();
    uv.extend(&face);
    let f1_wall = features(&h1, &w.uv, Some(&w.motif), &mut rng);
    let face1 = features(&h1, &face, None, &mut rng);
    let shift = Matrix3::new(1.0, 0.0, 0.37, 0.0, 1.0, -0.21, 0.0, 0.0, 1.0)
        * Matrix3::new(1.08, 0.0, 0.0, 0.0, 1.08, 0.0, 0.0, 0.0, 1.0);
    let f2_wall = features(&h2, &w.uv, Some(&w.motif), &mut rng);
    let mut face2 = features(&(h2 * shift), &face, None, &mut rng);
    face2.descriptors = face1.descriptors.clone();
    let join = |a: Features, b: Features| Features {
        keypoints: a.keypoints.iter().chain(&b.keypoints).copied().collect(),
        descriptors: Descriptors {
            dim: a.descriptors.dim,
            data: a
                .descriptors
                .data
                .iter()
                .chain(&b.descriptors.data)
                .copied()
                .collect(),
        },
    };
    let (f1, f2) = (join(f1_wall, face1), join(f2_wall, face2));
    let inliers: Vec<(u32, u32)> = (0..uv.len() as u32).map(|a| (a, a)).collect();
    assert_eq!(
        repeated_pattern(&f1, &f2, &inliers, 4.0, &RansacOptions::default()),
        None
    );
}

#[test]
fn the_basis_homography_passes_through_its_four_matches() {
    let h = Matrix3::new(0.9, 0.05, 30.0, -0.08, 1.1, -12.0, 2e-4, -1e-4, 1.0);
    let x = [(10.0, 20.0), (600.0, 40.0), (580.0, 400.0), (30.0, 450.0)];
    let s: Vec<Match2d2d> = x
        .iter()
        .map(|&(u, v)| {
            let a = Vector2::new(u, v);
            Match2d2d::new(a, apply(&h, a).unwrap())
        })
        .collect();
    let mut out = Vec::new();
    BasisHomography.fit(&s, &mut out);
    let g = out[0] / out[0][(2, 2)];
    assert!((g - h).norm() < 1e-9 * h.norm(), "{g} against {h}");
    // Three on a line: no homography.
    let mut line = s.clone();
    line[2] = Match2d2d::new(Vector2::new(305.0, 30.0), Vector2::new(1.0, 1.0));
    out.clear();
    BasisHomography.fit(&line, &mut out);
    assert!(out.is_empty());
}
