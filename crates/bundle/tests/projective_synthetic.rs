//! Projective bundle adjustment (§3.3) on a synthetic scene mapped by a projective transformation: the
//! reprojection error must fall to the noise level and the result must stay a projective transform of
//! the truth.

use std::collections::BTreeMap;

use handheld_bundle::{bundle_adjust_projective, BundleOptions, ProjectiveBundleConfig};
use handheld_core::pose::to_matrix3x4;
use handheld_core::{ProjectiveCamera, ProjectivePoint, ProjectiveReconstruction};
use handheld_testkit::multiview::{multi_view_set, MultiViewOptions};
use nalgebra::{DMatrix, Matrix4, Vector2, Vector4};

#[test]
fn projective_ba_reaches_noise_level_and_stays_projectively_equivalent() {
    let set = multi_view_set(&MultiViewOptions {
        num_views: 8,
        num_points: 400,
        noise_px: 0.5,
        seed: 3,
        ..Default::default()
    })
    .expect("valid");
    let gt = set.ground_truth();
    let noisy = &set.reconstruction;
    let t = Matrix4::new(
        1.0, 0.2, 0.0, 0.5, 0.1, 1.3, 0.1, 0.0, 0.05, 0.0, 0.9, 0.2, 0.02, 0.03, 0.01, 1.0,
    );
    let mut rec = ProjectiveReconstruction::default();
    for (id, v) in &gt.views {
        let k = gt.cameras[&v.camera_id].intrinsics.k_matrix();
        let mut p = k * to_matrix3x4(&v.cam_from_world);
        // Perturb all but the first camera.
        if id.0 > 0 {
            let s = id.0 as f64;
            for (i, e) in p.iter_mut().enumerate() {
                *e *= 1.0 + 2e-3 * ((i as f64 + s) * 1.7).sin();
            }
        }
        rec.cameras.insert(*id, ProjectiveCamera { P: p });
    }
    for (id, pt) in &gt.points {
        let s = id.0 as f64;
        let x = Vector4::new(
            pt.xyz.x + 0.02 * (s * 1.3).sin(),
            pt.xyz.y + 0.02 * (s * 0.7).cos(),
            pt.xyz.z,
            1.0,
        );
        rec.points
            .insert(*id, (ProjectivePoint { X: x }, pt.track.clone()));
    }
    rec.transform(&t).expect("invertible");
    let keypoints: BTreeMap<_, Vec<Vector2<f64>>> = noisy
        .views
        .iter()
        .map(|(id, v)| (*id, v.observations.iter().map(|o| o.xy).collect()))
        .collect();
    let opts = BundleOptions {
        num_threads: 2,
        ..Default::default()
    };
    let s = bundle_adjust_projective(
        &mut rec,
        &keypoints,
        &ProjectiveBundleConfig::default(),
        &opts,
    )
    .expect("runs");
    let gt_rms = {
        let e = noisy.reprojection_errors();
        (e.iter().map(|v| v * v).sum::<f64>() / e.len() as f64).sqrt()
    };
    println!("{s:?}\nrms at the truth {gt_rms:.4}");
    assert!(
        s.initial_rms_px > 1.5,
        "perturbation too small: {}",
        s.initial_rms_px
    );
    assert!(
        s.final_rms_px <= gt_rms,
        "final rms {} vs {gt_rms} at the truth",
        s.final_rms_px
    );
    assert!(s.final_rms_px > 0.8 * gt_rms);
    // Fit H with X_gt ~ H X_est (DLT, 3 equations per point) and measure the mapped point error.
    let ids: Vec<_> = gt.points.keys().copied().collect();
    let mut a = DMatrix::zeros(3 * ids.len(), 16);
    for (r, id) in ids.iter().enumerate() {
        let x = rec.points[id].0.X;
        let g = gt.points[id].xyz;
        for i in 0..3 {
            for j in 0..4 {
                a[(3 * r + i, 4 * i + j)] = x[j];
                a[(3 * r + i, 12 + j)] = -g[i] * x[j];
            }
        }
    }
    let svd = a.svd(false, true);
    let v_t = svd.v_t.expect("v");
    let (k, _) = svd.singular_values.argmin();
    let h = Matrix4::from_row_slice(v_t.row(k).transpose().as_slice());
    let mean_err = ids
        .iter()
        .map(|id| {
            let m = h * rec.points[id].0.X;
            (m.xyz() / m.w - gt.points[id].xyz.coords).norm()
        })
        .sum::<f64>()
        / ids.len() as f64;
    println!("mean point error after projective alignment {mean_err:.5} (scene radius 1.5)");
    assert!(mean_err < 0.01, "{mean_err}");
}
