//! The cheap correspondence sets satisfy their exact models: epipolar constraint for inliers,
//! homographies for planar and pure-rotation sets, exact projection for resection, and the requested
//! outlier fraction with outliers far from every model.

use handheld_testkit::correspondences::{epipolar_distance, transfer_error, OUTLIER_MIN_ERROR_PX};
use handheld_testkit::{
    resection_set, two_view_set, ResectionOptions, TwoViewKind, TwoViewOptions,
};
use nalgebra::Vector4;

const KINDS: [TwoViewKind; 4] = [
    TwoViewKind::General,
    TwoViewKind::Planar,
    TwoViewKind::PureRotation,
    TwoViewKind::PureTranslation,
];

#[test]
fn noise_free_inliers_satisfy_the_epipolar_constraint() {
    for kind in [
        TwoViewKind::General,
        TwoViewKind::Planar,
        TwoViewKind::PureTranslation,
    ] {
        let set = two_view_set(&TwoViewOptions {
            kind,
            noise_px: 0.0,
            seed: 3,
            ..Default::default()
        })
        .expect("valid");
        let f = set.fundamental_matrix().expect("F exists with a baseline");
        // Rank 2, unit norm.
        let sv = f.singular_values();
        assert!(
            sv.min() < 1e-12 && (f.norm() - 1.0).abs() < 1e-12,
            "{kind:?}: {sv:?}"
        );
        for (a, b) in set.x1.iter().zip(&set.x2) {
            let algebraic = b.push(1.0).dot(&(f * a.push(1.0)));
            assert!(algebraic.abs() < 1e-9, "{kind:?}: x2ᵀFx1 = {algebraic}");
            assert!(epipolar_distance(&f, a, b) < 1e-7);
        }
        assert_eq!(set.points3d.len(), 200);
        assert!(set.is_inlier.iter().all(|b| *b));
    }
}

#[test]
fn homographies_hold_for_planar_and_rotation_sets() {
    for kind in [TwoViewKind::Planar, TwoViewKind::PureRotation] {
        let set = two_view_set(&TwoViewOptions {
            kind,
            noise_px: 0.0,
            seed: 8,
            ..Default::default()
        })
        .expect("valid");
        let h = set.homography().expect("H exists");
        for (a, b) in set.x1.iter().zip(&set.x2) {
            assert!(transfer_error(&h, a, b) < 1e-7, "{kind:?}");
        }
        if let Some((n, d)) = set.plane {
            assert!(set
                .points3d
                .iter()
                .all(|p| (n.dot(&p.coords) - d).abs() < 1e-9));
        }
    }
    let rot = two_view_set(&TwoViewOptions {
        kind: TwoViewKind::PureRotation,
        ..Default::default()
    })
    .expect("valid");
    assert!(rot.fundamental_matrix().is_none());
    assert!(rot.relative_pose().translation.vector.norm() < 1e-12);
    let general = two_view_set(&TwoViewOptions::default()).expect("valid");
    assert!(general.homography().is_none());
}

#[test]
fn outlier_fraction_and_noise_are_respected() {
    for kind in KINDS {
        let opts = TwoViewOptions {
            kind,
            n: 300,
            noise_px: 0.7,
            outlier_fraction: 0.3,
            seed: 21,
            ..Default::default()
        };
        let set = two_view_set(&opts).expect("valid");
        assert_eq!(
            set.is_inlier.iter().filter(|b| !**b).count(),
            90,
            "{kind:?}"
        );
        let (f, h) = (set.fundamental_matrix(), set.homography());
        let mut sq = 0.0;
        for i in 0..set.x1.len() {
            let model_err = |a: &nalgebra::Vector2<f64>, b: &nalgebra::Vector2<f64>| {
                let ef = f.map_or(f64::INFINITY, |f| epipolar_distance(&f, a, b));
                let eh = h.map_or(f64::INFINITY, |h| transfer_error(&h, a, b));
                ef.min(eh)
            };
            if set.is_inlier[i] {
                sq += (set.x1[i] - set.x1_exact[i]).norm_squared()
                    + (set.x2[i] - set.x2_exact[i]).norm_squared();
                assert!(
                    model_err(&set.x1[i], &set.x2[i]) < 10.0 * opts.noise_px,
                    "{kind:?} inlier {i}"
                );
            } else {
                assert!(
                    model_err(&set.x1_exact[i], &set.x2[i]) > OUTLIER_MIN_ERROR_PX,
                    "{kind:?} outlier {i}"
                );
                assert!(set.camera2.contains(&set.x2[i]));
            }
        }
        let sigma = (sq / (4.0 * set.num_inliers() as f64)).sqrt();
        assert!((sigma - 0.7).abs() < 0.07, "{kind:?}: noise σ {sigma}");
    }
}

#[test]
fn sets_are_deterministic_in_the_seed() {
    let a = two_view_set(&TwoViewOptions {
        outlier_fraction: 0.2,
        seed: 4,
        ..Default::default()
    })
    .expect("valid");
    let b = two_view_set(&TwoViewOptions {
        outlier_fraction: 0.2,
        seed: 4,
        ..Default::default()
    })
    .expect("valid");
    let c = two_view_set(&TwoViewOptions {
        outlier_fraction: 0.2,
        seed: 5,
        ..Default::default()
    })
    .expect("valid");
    assert_eq!(a, b);
    assert_ne!(a, c);
}

#[test]
fn resection_sets_project_exactly() {
    for (planar, k1) in [(false, 0.0), (true, 0.0), (false, -0.1)] {
        let opts = ResectionOptions {
            planar,
            k1,
            noise_px: 0.0,
            outlier_fraction: 0.25,
            seed: 9,
            ..Default::default()
        };
        let set = resection_set(&opts).expect("valid");
        let p = set.projection_matrix();
        for (i, x) in set.points3d.iter().enumerate() {
            let px = set.camera.project(&set.pose, x).expect("in front");
            assert!((px - set.x_exact[i]).norm() < 1e-9);
            if k1 == 0.0 {
                let m = p * Vector4::new(x.x, x.y, x.z, 1.0);
                assert!((m.xy() / m.z - set.x_exact[i]).norm() < 1e-9);
            }
            if planar {
                assert_eq!(x.z, 0.0);
            }
            if set.is_inlier[i] {
                assert_eq!(set.x[i], set.x_exact[i]);
            } else {
                assert!((set.x[i] - set.x_exact[i]).norm() > OUTLIER_MIN_ERROR_PX);
            }
        }
        assert_eq!(set.is_inlier.iter().filter(|b| !**b).count(), 25);
        assert!(set.center().coords.norm() > 4.0);
    }
}
