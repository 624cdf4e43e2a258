//! SIFT + matching (issue #3): repeatability and matching precision under a known similarity on a
//! rendered image, the GEMM matcher against a naive O(nm) reference, ratio/mutual semantics, and
//! real-data epipolar consistency on fountain-P11 (ignored when `../shared/datasets/fountain-P11` is
//! absent; with `CI` set it runs and fails naming it).

use handheld_features::matching::{match_descriptors, match_pairs, Match, MatchOptions};
use handheld_features::sift::{Sift, SiftOptions, SIFT_DIM};
use handheld_features::{Descriptors, FeatureDetector, Features, GrayImage};
use handheld_testkit::render::{render_sequence, SequenceOptions};
use nalgebra::{Matrix3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn rendered_image() -> GrayImage {
    let opts = SequenceOptions {
        num_frames: 2,
        ..Default::default()
    };
    let seq = render_sequence(&opts).expect("render");
    GrayImage::from_rgb8(&seq.images[0])
}

/// The similarity `q = s·R(θ)(p − c) + c` about the image centre, and its inverse.
struct Similarity {
    s: f32,
    cos: f32,
    sin: f32,
    cx: f32,
    cy: f32,
}

impl Similarity {
    fn apply(&self, x: f32, y: f32) -> (f32, f32) {
        let (dx, dy) = (x - self.cx, y - self.cy);
        (
            self.s * (self.cos * dx - self.sin * dy) + self.cx,
            self.s * (self.sin * dx + self.cos * dy) + self.cy,
        )
    }
    fn invert(&self, x: f32, y: f32) -> (f32, f32) {
        let (dx, dy) = ((x - self.cx) / self.s, (y - self.cy) / self.s);
        (
            self.cos * dx + self.sin * dy + self.cx,
            -self.sin * dx + self.cos * dy + self.cy,
        )
    }
}

fn warp(img: &GrayImage, t: &Similarity) -> GrayImage {
    let mut out = GrayImage::new(img.width, img.height);
    for y in 0..img.height {
        for x in 0..img.width {
            let (sx, sy) = t.invert(x as f32, y as f32);
            out.data[y * img.width + x] = if img.inside(sx, sy, 0.0) {
                img.sample(sx, sy)
            } else {
                0.5
            };
        }
    }
    out
}

#[test]
fn sift_is_repeatable_and_matches_under_similarity() {
    let img1 = rendered_image();
    let t = Similarity {
        s: 0.8,
        cos: 30f32.to_radians().cos(),
        sin: 30f32.to_radians().sin(),
        cx: 319.5,
        cy: 239.5,
    };
    let img2 = warp(&img1, &t);
    let sift = Sift::new(SiftOptions {
        max_features: None,
        ..Default::default()
    });
    assert_eq!(sift.name(), "rootsift");
    let (f1, f2) = (sift.detect(&img1), sift.detect(&img2));
    assert_eq!(f1.descriptors.dim, SIFT_DIM);
    assert_eq!(f1.descriptors.len(), f1.keypoints.len());
    for r in 0..f1.descriptors.len() {
        let n2: f32 = f1.descriptors.row(r).iter().map(|v| v * v).sum();
        assert!((n2 - 1.0).abs() < 1e-3, "RootSIFT rows have unit L2 norm");
    }
    // Repeatability (Mikolajczyk et al. 2005): keypoints in the common region (away from the border
    // and the fill) with a detection in the other image within 1.5 px, over the smaller visible count.
    let common = |x: f32, y: f32| {
        let (u, v) = t.apply(x, y);
        img1.inside(x, y, 12.0) && img2.inside(u, v, 12.0)
    };
    let visible1: Vec<(f32, f32)> = f1
        .keypoints
        .iter()
        .filter(|k| common(k.x, k.y))
        .map(|k| t.apply(k.x, k.y))
        .collect();
    let visible2 = f2.keypoints.iter().filter(|k| {
        let (x, y) = t.invert(k.x, k.y);
        common(x, y)
    });
    let visible = visible1.len().min(visible2.count());
    let repeated = visible1
        .iter()
        .filter(|(x, y)| {
            f2.keypoints
                .iter()
                .any(|q| (q.x - x).powi(2) + (q.y - y).powi(2) < 1.5f32.powi(2))
        })
        .count();
    let repeatability = repeated as f64 / visible.max(1) as f64;
    let matches = match_descriptors(&f1.descriptors, &f2.descriptors, &MatchOptions::default());
    let correct = matches
        .iter()
        .filter(|m| {
            let (p, q) = (f1.keypoints[m.i as usize], f2.keypoints[m.j as usize]);
            let (x, y) = t.apply(p.x, p.y);
            (q.x - x).powi(2) + (q.y - y).powi(2) < 4.0
        })
        .count();
    let precision = correct as f64 / matches.len().max(1) as f64;
    println!(
        "keypoints {} / {}, repeatability {repeatability:.3} of {visible}, matches {}, precision {precision:.3}",
        f1.keypoints.len(),
        f2.keypoints.len(),
        matches.len()
    );
    assert!(visible > 150, "too few keypoints: {visible}");
    assert!(repeatability >= 0.6, "repeatability {repeatability}");
    assert!(matches.len() > 100, "matches {}", matches.len());
    assert!(precision >= 0.9, "precision {precision}");
}

#[test]
fn sift_options_validate() {
    assert!(SiftOptions::default().validate().is_ok());
    assert!(SiftOptions {
        octave_layers: 0,
        ..Default::default()
    }
    .validate()
    .is_err());
    assert!(SiftOptions {
        sigma: f32::NAN,
        ..Default::default()
    }
    .validate()
    .is_err());
    assert!(SiftOptions {
        edge_threshold: 0.5,
        ..Default::default()
    }
    .validate()
    .is_err());
    assert!(SiftOptions {
        max_features: Some(0),
        ..Default::default()
    }
    .validate()
    .is_err());
    assert!(SiftOptions {
        num_octaves: Some(0),
        ..Default::default()
    }
    .validate()
    .is_err());
    assert_eq!(
        Sift::new(SiftOptions {
            root_sift: false,
            ..Default::default()
        })
        .name(),
        "sift"
    );
}

#[test]
fn sift_handles_tiny_and_flat_images() {
    let sift = Sift::default();
    assert!(sift.detect(&GrayImage::new(8, 8)).keypoints.is_empty());
    let f = sift.detect(&GrayImage {
        width: 64,
        height: 48,
        data: vec![0.5; 64 * 48],
    });
    assert!(f.keypoints.is_empty() && f.descriptors.is_empty());
    let bad = Sift::new(SiftOptions {
        octave_layers: 0,
        ..Default::default()
    });
    assert!(bad.detect(&rendered_image()).keypoints.is_empty());
}

#[test]
fn max_features_keeps_the_strongest() {
    let img = rendered_image();
    let all = Sift::new(SiftOptions {
        max_features: None,
        ..Default::default()
    })
    .detect(&img);
    let few = Sift::new(SiftOptions {
        max_features: Some(50),
        ..Default::default()
    })
    .detect(&img);
    assert_eq!(few.keypoints.len(), 50);
    let mut responses: Vec<f32> = all.keypoints.iter().map(|k| k.response).collect();
    responses.sort_by(|a, b| b.total_cmp(a));
    let weakest_kept = few
        .keypoints
        .iter()
        .map(|k| k.response)
        .fold(f32::INFINITY, f32::min);
    assert!(weakest_kept >= responses[60.min(responses.len() - 1)]);
}

/// Unit-norm random descriptors; `b` holds noisy copies of the first `copies` rows of `a` then distractors.
fn random_sets(n: usize, m: usize, copies: usize, seed: u64) -> (Descriptors, Descriptors) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let d = 32;
    let unit = |v: Vec<f32>| {
        let n = v.iter().map(|x| x * x).sum::<f32>().sqrt();
        v.into_iter().map(|x| x / n).collect::<Vec<_>>()
    };
    let a: Vec<Vec<f32>> = (0..n)
        .map(|_| unit((0..d).map(|_| rng.random::<f32>()).collect()))
        .collect();
    let mut b: Vec<Vec<f32>> = Vec::new();
    for i in 0..m {
        let v = if let Some(src) = a.get(i).filter(|_| i < copies) {
            let noise = rng.random::<f32>() * 0.3;
            unit(
                src.iter()
                    .map(|x| x + noise * (rng.random::<f32>() - 0.5))
                    .collect(),
            )
        } else {
            unit((0..d).map(|_| rng.random::<f32>()).collect())
        };
        b.push(v);
    }
    let flat = |v: Vec<Vec<f32>>| Descriptors {
        dim: d,
        data: v.concat(),
    };
    (flat(a), flat(b))
}

/// O(nm) reference in f64 with the documented semantics; also reports whether a row is a near tie.
/// Descriptors in [0, 1] are compared as the matcher does, quantised to multiples of 1/512.
fn naive(a: &Descriptors, b: &Descriptors, o: &MatchOptions) -> (Vec<Match>, Vec<bool>) {
    let quantise = a
        .data
        .iter()
        .chain(&b.data)
        .all(|v| (0.0..=1.0).contains(v));
    let value = |p: f32| {
        if quantise {
            f64::from((p * 512.0).round().clamp(0.0, 255.0)) / 512.0
        } else {
            f64::from(p)
        }
    };
    let dist2 = |x: &[f32], y: &[f32]| {
        x.iter()
            .zip(y)
            .map(|(p, q)| (value(*p) - value(*q)).powi(2))
            .sum::<f64>()
    };
    let nearest = |row: &[f32], set: &Descriptors| {
        let mut v: Vec<(f64, usize)> = (0..set.len())
            .map(|j| (dist2(row, set.row(j)), j))
            .collect();
        v.sort_by(|p, q| p.0.total_cmp(&q.0).then(p.1.cmp(&q.1)));
        v
    };
    let (mut out, mut fragile) = (Vec::new(), Vec::new());
    for i in 0..a.len() {
        let v = nearest(a.row(i), b);
        let (d1, j) = v[0];
        let d2 = v.get(1).map_or(f64::INFINITY, |x| x.0);
        let r = (d1 / d2).sqrt();
        let back = nearest(b.row(j), a);
        fragile.push(
            (r - o.ratio as f64).abs() < 1e-3
                || (d2 - d1) < 1e-5
                || back.get(1).is_some_and(|x| x.0 - back[0].0 < 1e-5),
        );
        let ok = (o.ratio >= 1.0 || r < o.ratio as f64)
            && (!o.mutual || back[0].1 == i)
            && !o.max_distance.is_some_and(|t| d1.sqrt() > t as f64);
        if ok {
            out.push(Match {
                i: i as u32,
                j: j as u32,
                distance: d1.sqrt() as f32,
            });
        }
    }
    (out, fragile)
}

#[test]
fn matcher_equals_naive_reference() {
    // Sizes cross the 256-row and 1024-column blocks.
    let (a, b) = random_sets(600, 1300, 400, 7);
    let variants = [
        MatchOptions::default(),
        MatchOptions {
            mutual: false,
            ..Default::default()
        },
        MatchOptions {
            ratio: 1.0,
            mutual: false,
            max_distance: None,
            ..Default::default()
        },
        MatchOptions {
            ratio: 1.0,
            mutual: true,
            max_distance: Some(0.2),
            ..Default::default()
        },
        MatchOptions {
            ratio: 0.6,
            mutual: true,
            max_distance: None,
            ..Default::default()
        },
        MatchOptions {
            coarse_to_fine: false,
            ..Default::default()
        },
    ];
    for o in &variants {
        let got = match_descriptors(&a, &b, o);
        let (want, fragile) = naive(&a, &b, o);
        let key = |m: &Match| (m.i, m.j);
        let got_keys: Vec<_> = got
            .iter()
            .map(key)
            .filter(|k| !fragile[k.0 as usize])
            .collect();
        let want_keys: Vec<_> = want
            .iter()
            .map(key)
            .filter(|k| !fragile[k.0 as usize])
            .collect();
        assert_eq!(got_keys, want_keys, "options {o:?}");
        assert!(
            want.len() > 50,
            "test has too few matches ({}) for {o:?}",
            want.len()
        );
        for (g, w) in got.iter().zip(&want).filter(|(g, w)| key(g) == key(w)) {
            assert!((g.distance - w.distance).abs() < 1e-3);
        }
    }
    // Parallel-over-pairs wrapper agrees and tolerates bad indices.
    let feats = vec![
        Features {
            keypoints: vec![],
            descriptors: a.clone(),
        },
        Features {
            keypoints: vec![],
            descriptors: b.clone(),
        },
    ];
    let per_pair = match_pairs(&feats, &[(0, 1), (1, 0), (0, 9)], &MatchOptions::default());
    assert_eq!(
        per_pair[0],
        match_descriptors(&a, &b, &MatchOptions::default())
    );
    assert!(!per_pair[1].is_empty() && per_pair[2].is_empty());
}

#[test]
fn ratio_and_mutual_semantics() {
    let d = |rows: &[[f32; 2]]| Descriptors {
        dim: 2,
        data: rows.iter().flatten().copied().collect(),
    };
    // a0 is 0.1 from b0 and 0.15 from b1: ratio 0.67.
    let a = d(&[[0.0, 0.0]]);
    let b = d(&[[0.1, 0.0], [0.0, 0.15]]);
    let m = match_descriptors(
        &a,
        &b,
        &MatchOptions {
            ratio: 0.8,
            ..Default::default()
        },
    );
    assert_eq!(m.len(), 1);
    assert_eq!((m[0].i, m[0].j), (0, 0));
    // Quantised to multiples of 1/512: 0.1 is 51/512.
    assert!((m[0].distance - 51.0 / 512.0).abs() < 1e-6);
    assert!(match_descriptors(
        &a,
        &b,
        &MatchOptions {
            ratio: 0.6,
            ..Default::default()
        }
    )
    .is_empty());
    assert!(match_descriptors(
        &a,
        &b,
        &MatchOptions {
            max_distance: Some(0.05),
            ..Default::default()
        }
    )
    .is_empty());
    // Two rows of a share the nearest b0; only the nearer one survives the mutual check.
    let a = d(&[[0.0, 0.0], [0.3, 0.0]]);
    let b = d(&[[0.2, 0.0], [5.0, 5.0]]);
    let one_way = match_descriptors(
        &a,
        &b,
        &MatchOptions {
            mutual: false,
            ..Default::default()
        },
    );
    assert_eq!(
        one_way.iter().map(|m| (m.i, m.j)).collect::<Vec<_>>(),
        vec![(0, 0), (1, 0)]
    );
    let mutual = match_descriptors(&a, &b, &MatchOptions::default());
    assert_eq!(
        mutual.iter().map(|m| (m.i, m.j)).collect::<Vec<_>>(),
        vec![(1, 0)]
    );
    // A single candidate has no second neighbour: the ratio test passes; mismatched dims give nothing.
    assert_eq!(
        match_descriptors(&a, &d(&[[0.0, 0.1]]), &MatchOptions::default()).len(),
        1
    );
    assert!(match_descriptors(
        &a,
        &Descriptors {
            dim: 3,
            data: vec![0.0; 3]
        },
        &MatchOptions::default()
    )
    .is_empty());
    assert!(match_descriptors(&a, &Descriptors::default(), &MatchOptions::default()).is_empty());
}

/// `(K, R, C)` of a Strecha `.camera` file (P = K [Rᵀ | −Rᵀ C]).
fn strecha_camera(path: &std::path::Path) -> (Matrix3<f64>, Matrix3<f64>, Vector3<f64>) {
    let text = std::fs::read_to_string(path).expect("camera file");
    let v: Vec<f64> = text
        .split_whitespace()
        .map(|t| t.parse().expect("number"))
        .collect();
    (
        Matrix3::from_row_slice(&v[0..9]),
        Matrix3::from_row_slice(&v[12..21]),
        Vector3::new(v[21], v[22], v[23]),
    )
}

/// Fundamental matrix with `x₂ᵀ F x₁ = 0` from two Strecha cameras.
fn strecha_fundamental(c1: &std::path::Path, c2: &std::path::Path) -> Matrix3<f64> {
    let ((k1, r1, cc1), (k2, r2, cc2)) = (strecha_camera(c1), strecha_camera(c2));
    let r = r2.transpose() * r1;
    let t = r2.transpose() * (cc1 - cc2);
    let e = t.cross_matrix() * r;
    k2.try_inverse().expect("K").transpose() * e * k1.try_inverse().expect("K")
}

#[test]
#[cfg_attr(
    not(has_fountain),
    ignore = "needs ../shared/datasets/fountain-P11 (missing)"
)]
fn fountain_matches_are_epipolar_consistent() {
    let dir = handheld_testkit::needs::dataset(env!("HANDHELD_DATASETS_DIR"), "fountain-P11");
    let load = |name: &str| {
        GrayImage::from_dynamic(&image::open(dir.join("images").join(name)).expect("decode"))
    };
    let (g1, g2) = (load("0000.jpg"), load("0001.jpg"));
    let sift = Sift::default();
    let (f1, f2) = (sift.detect(&g1), sift.detect(&g2));
    let matches = match_descriptors(&f1.descriptors, &f2.descriptors, &MatchOptions::default());
    let f = strecha_fundamental(
        &dir.join("gt/0000.jpg.camera"),
        &dir.join("gt/0001.jpg.camera"),
    );
    let good = matches
        .iter()
        .filter(|m| {
            let (p, q) = (f1.keypoints[m.i as usize], f2.keypoints[m.j as usize]);
            let x1 = Vector3::new(p.x as f64, p.y as f64, 1.0);
            let x2 = Vector3::new(q.x as f64, q.y as f64, 1.0);
            let l = f * x1;
            (x2.dot(&l)).abs() / (l.x * l.x + l.y * l.y).sqrt() < 2.0
        })
        .count();
    let frac = good as f64 / matches.len().max(1) as f64;
    println!(
        "fountain 0000-0001 at 3072×2048: {} / {} keypoints, {} matches, {:.3} within 2 px of the GT epipolar line",
        f1.keypoints.len(),
        f2.keypoints.len(),
        matches.len(),
        frac
    );
    assert!(matches.len() > 1000, "matches {}", matches.len());
    assert!(frac > 0.9, "epipolar-consistent fraction {frac}");
}
