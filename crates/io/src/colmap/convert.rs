//! Conversion between [`ColmapModel`] and Handheld's [`MetricReconstruction`].
//!
//! Handheld puts the centre of the top-left pixel at `(0, 0)`, COLMAP at `(0.5, 0.5)`: principal
//! points and keypoints gain [`PIXEL_CENTER_OFFSET_COLMAP`] on export and lose it on import. Poses
//! are `cam_from_world` on both sides (COLMAP's quaternion is `w, x, y, z`). On export the camera
//! model is the simplest that holds the intrinsics exactly (COLMAP has no skew); on import all five
//! supported models are understood.

use handheld_core::{
    Camera, CameraId, ImageId, Intrinsics, MetricReconstruction, Observation, Point3D, PointId,
    Rigid3, Track, TrackElement, View, PIXEL_CENTER_OFFSET_COLMAP,
};
use nalgebra::{Point3, Quaternion, Translation3, UnitQuaternion, Vector2};

use super::{
    check_params, CameraModel, ColmapCamera, ColmapImage, ColmapModel, ColmapPoint2D, ColmapPoint3D,
};

const OFF: f64 = PIXEL_CENTER_OFFSET_COLMAP;

/// Converts a reconstruction to a COLMAP model. Fails for a camera with skew (COLMAP cannot store it).
///
/// Model choice: square pixels give `SIMPLE_RADIAL` (`k2 = 0`) or `RADIAL`; other aspect ratios give
/// `PINHOLE` without distortion and `OPENCV` (with `p1 = p2 = 0`) with it.
pub fn to_colmap(rec: &MetricReconstruction) -> Result<ColmapModel, String> {
    let mut m = ColmapModel::default();
    for cam in rec.cameras.values() {
        let c = camera_to_colmap(cam)?;
        m.cameras.insert(c.id, c);
    }
    for v in rec.views.values() {
        let q = v.cam_from_world.rotation;
        let t = v.cam_from_world.translation.vector;
        let points2d = v
            .observations
            .iter()
            .map(|o| ColmapPoint2D {
                x: o.xy.x + OFF,
                y: o.xy.y + OFF,
                point3d_id: o.point_id.map(|p| p.0),
            })
            .collect();
        m.images.insert(
            v.id.0,
            ColmapImage {
                id: v.id.0,
                qvec: [q.w, q.i, q.j, q.k],
                tvec: [t.x, t.y, t.z],
                camera_id: v.camera_id.0,
                name: v.name.clone(),
                points2d,
            },
        );
    }
    for (id, p) in &rec.points {
        m.points3d.insert(
            id.0,
            ColmapPoint3D {
                id: id.0,
                xyz: [p.xyz.x, p.xyz.y, p.xyz.z],
                rgb: p.color,
                error: p.error,
                track: p
                    .track
                    .elements
                    .iter()
                    .map(|e| (e.image_id.0, e.point2d_idx))
                    .collect(),
            },
        );
    }
    Ok(m)
}

/// One camera in COLMAP's form (model, parameters in its pixel convention), as [`to_colmap`] writes it.
pub fn camera_to_colmap(cam: &Camera) -> Result<ColmapCamera, String> {
    let k = &cam.intrinsics;
    if k.skew != 0.0 {
        return Err(format!(
            "camera {}: skew is {}, but COLMAP's camera models have no skew; fix it to 0 (e.g. in bundle adjustment) before exporting",
            cam.id, k.skew
        ));
    }
    let (cx, cy) = (k.pp.x + OFF, k.pp.y + OFF);
    let (model, params) = if k.aspect == 1.0 {
        if k.k2 == 0.0 {
            (CameraModel::SimpleRadial, vec![k.f, cx, cy, k.k1])
        } else {
            (CameraModel::Radial, vec![k.f, cx, cy, k.k1, k.k2])
        }
    } else {
        let fy = k.aspect * k.f;
        if k.is_undistorted() {
            (CameraModel::Pinhole, vec![k.f, fy, cx, cy])
        } else {
            (
                CameraModel::Opencv,
                vec![k.f, fy, cx, cy, k.k1, k.k2, 0.0, 0.0],
            )
        }
    };
    Ok(ColmapCamera {
        id: cam.id.0,
        model,
        width: cam.width as u64,
        height: cam.height as u64,
        params,
    })
}

fn camera_from_colmap(c: &ColmapCamera) -> Result<Camera, String> {
    check_params(c)?;
    let p = &c.params;
    // (f, fy, cx, cy, k1, k2)
    let (f, fy, cx, cy, k1, k2) = match c.model {
        CameraModel::SimplePinhole => (p[0], p[0], p[1], p[2], 0.0, 0.0),
        CameraModel::Pinhole => (p[0], p[1], p[2], p[3], 0.0, 0.0),
        CameraModel::SimpleRadial => (p[0], p[0], p[1], p[2], p[3], 0.0),
        CameraModel::Radial => (p[0], p[0], p[1], p[2], p[3], p[4]),
        CameraModel::Opencv => {
            if p[6] != 0.0 || p[7] != 0.0 {
                return Err(format!(
                    "camera {}: OPENCV tangential distortion p1 = {}, p2 = {} is not supported by Handheld (only radial k1, k2)",
                    c.id, p[6], p[7]
                ));
            }
            (p[0], p[1], p[2], p[3], p[4], p[5])
        }
    };
    let aspect = if fy == f { 1.0 } else { fy / f };
    let width = u32::try_from(c.width)
        .map_err(|_| format!("camera {}: width {} is too large", c.id, c.width))?;
    let height = u32::try_from(c.height)
        .map_err(|_| format!("camera {}: height {} is too large", c.id, c.height))?;
    let intrinsics = Intrinsics {
        f,
        aspect,
        skew: 0.0,
        pp: Vector2::new(cx - OFF, cy - OFF),
        k1,
        k2,
    };
    intrinsics
        .validate()
        .map_err(|e| format!("camera {}: {e}", c.id))?;
    Ok(Camera {
        id: CameraId(c.id),
        width,
        height,
        intrinsics,
    })
}

fn pose_from_colmap(im: &ColmapImage) -> Result<Rigid3, String> {
    let [w, x, y, z] = im.qvec;
    let q = Quaternion::new(w, x, y, z);
    let norm = q.norm();
    if !norm.is_finite() || norm < 1e-12 || im.tvec.iter().any(|v| !v.is_finite()) {
        return Err(format!(
            "image {} ({}): invalid pose qvec {:?}, tvec {:?}",
            im.id, im.name, im.qvec, im.tvec
        ));
    }
    let [tx, ty, tz] = im.tvec;
    Ok(Rigid3::from_parts(
        Translation3::new(tx, ty, tz),
        UnitQuaternion::from_quaternion(q),
    ))
}

/// Converts a COLMAP model to a reconstruction and checks its internal references (every image's
/// camera exists, every track element refers to a keypoint that refers back to its point).
pub fn from_colmap(m: &ColmapModel) -> Result<MetricReconstruction, String> {
    let mut rec = MetricReconstruction::default();
    for c in m.cameras.values() {
        rec.cameras.insert(CameraId(c.id), camera_from_colmap(c)?);
    }
    for im in m.images.values() {
        let observations = im
            .points2d
            .iter()
            .map(|p| Observation {
                xy: Vector2::new(p.x - OFF, p.y - OFF),
                point_id: p.point3d_id.map(PointId),
            })
            .collect();
        rec.views.insert(
            ImageId(im.id),
            View {
                id: ImageId(im.id),
                name: im.name.clone(),
                camera_id: CameraId(im.camera_id),
                cam_from_world: pose_from_colmap(im)?,
                observations,
                frame: None,
            },
        );
    }
    for p in m.points3d.values() {
        let elements = p
            .track
            .iter()
            .map(|&(i, k)| TrackElement {
                image_id: ImageId(i),
                point2d_idx: k,
            })
            .collect();
        rec.points.insert(
            PointId(p.id),
            Point3D {
                xyz: Point3::new(p.xyz[0], p.xyz[1], p.xyz[2]),
                color: p.rgb,
                error: p.error,
                track: Track { elements },
            },
        );
    }
    rec.validate()?;
    Ok(rec)
}

#[cfg(test)]
mod tests {
    use super::super::{read_model, read_reconstruction, write_reconstruction};
    use super::*;
    use handheld_core::pose::cam_from_world_from_center;
    use nalgebra::Rotation3;

    /// Values are multiples of 1/8 so the ±0.5 shift is exact.
    fn sample_rec() -> MetricReconstruction {
        let mut rec = MetricReconstruction::default();
        let kinds = [
            (1.0, 0.0, 0.0),      // SIMPLE_RADIAL with k1 = 0
            (1.0, -0.125, 0.0),   // SIMPLE_RADIAL
            (1.0, -0.25, 0.0625), // RADIAL
            (1.25, 0.0, 0.0),     // PINHOLE
            (0.75, 0.125, -0.5),  // OPENCV
        ];
        for (i, &(aspect, k1, k2)) in kinds.iter().enumerate() {
            let id = CameraId(i as u32 + 10);
            let intrinsics = Intrinsics {
                f: 512.0 + i as f64,
                aspect,
                skew: 0.0,
                pp: Vector2::new(319.375, 239.625 - i as f64),
                k1,
                k2,
            };
            rec.cameras.insert(
                id,
                Camera {
                    id,
                    width: 640,
                    height: 480,
                    intrinsics,
                },
            );
        }
        for i in 0..6u32 {
            let id = ImageId(i * 3 + 1);
            let r = Rotation3::from_euler_angles(0.1 * i as f64, -0.3, 0.7 - 0.2 * i as f64);
            let pose =
                cam_from_world_from_center(&r, &Point3::new(i as f64, -0.5, -4.0 - i as f64 / 3.0));
            let n = if i == 2 { 0 } else { 30 };
            let observations = (0..n)
                .map(|k| Observation {
                    xy: Vector2::new(k as f64 * 10.125 - 0.375, 479.5 - k as f64 * 0.875),
                    point_id: (k % 2 == 0 && k / 2 < 12).then_some(PointId(1000 + (k / 2) as u64)),
                })
                .collect();
            rec.views.insert(
                id,
                View {
                    id,
                    name: format!("img_{i}.png"),
                    camera_id: CameraId(10 + i % 5),
                    cam_from_world: pose,
                    observations,
                    frame: None,
                },
            );
        }
        for j in 0..12u64 {
            let elements = rec
                .views
                .values()
                .filter(|v| !v.observations.is_empty())
                .map(|v| TrackElement {
                    image_id: v.id,
                    point2d_idx: (2 * j) as u32,
                })
                .collect();
            rec.points.insert(
                PointId(1000 + j),
                Point3D {
                    xyz: Point3::new(j as f64 * 0.1, 1.0 / 3.0, 2.0),
                    color: [j as u8, 200, 7],
                    error: 0.25,
                    track: Track { elements },
                },
            );
        }
        rec.validate().unwrap();
        rec
    }

    fn assert_rec_eq(a: &MetricReconstruction, b: &MetricReconstruction) {
        assert_eq!(a.cameras, b.cameras);
        assert_eq!(a.points, b.points);
        assert_eq!(a.views.len(), b.views.len());
        for (va, vb) in a.views.values().zip(b.views.values()) {
            assert_eq!(
                (va.id, &va.name, va.camera_id, &va.observations, va.frame),
                (vb.id, &vb.name, vb.camera_id, &vb.observations, vb.frame)
            );
            assert!(
                va.cam_from_world
                    .rotation
                    .angle_to(&vb.cam_from_world.rotation)
                    < 1e-12
            );
            assert!(
                (va.cam_from_world.translation.vector - vb.cam_from_world.translation.vector)
                    .norm()
                    < 1e-12
            );
        }
    }

    #[test]
    fn export_picks_models_and_shifts_pixels() {
        let rec = sample_rec();
        let m = to_colmap(&rec).unwrap();
        let models: Vec<_> = m.cameras.values().map(|c| c.model).collect();
        use CameraModel::*;
        assert_eq!(
            models,
            vec![SimpleRadial, SimpleRadial, Radial, Pinhole, Opencv]
        );
        assert_eq!(m.cameras[&10].params, vec![512.0, 319.875, 240.125, 0.0]);
        assert_eq!(m.cameras[&13].params, vec![515.0, 643.75, 319.875, 237.125]);
        assert_eq!(m.cameras[&14].params[4..], [0.125, -0.5, 0.0, 0.0]);
        let p = m.images[&1].points2d[1];
        assert_eq!(
            (p.x, p.y, p.point3d_id),
            (10.125 - 0.375 + 0.5, 479.5 - 0.875 + 0.5, None)
        );
        assert_eq!(m.images[&1].points2d[0].point3d_id, Some(1000));
    }

    #[test]
    fn reconstruction_round_trips_through_text_and_binary() {
        let rec = sample_rec();
        for (text, binary) in [(true, false), (false, true), (true, true)] {
            let dir = tempfile::tempdir().unwrap();
            write_reconstruction(dir.path(), &rec, text, binary).unwrap();
            assert_eq!(dir.path().join("cameras.bin").exists(), binary);
            let back = from_colmap(&read_model(dir.path()).unwrap()).unwrap();
            assert_rec_eq(&rec, &back);
            assert_rec_eq(&rec, &read_reconstruction(dir.path()).unwrap());
        }
    }

    #[test]
    fn skew_is_refused() {
        let mut rec = sample_rec();
        rec.cameras.get_mut(&CameraId(11)).unwrap().intrinsics.skew = 0.5;
        let e = to_colmap(&rec).unwrap_err();
        assert!(e.contains("skew") && e.contains("11"), "{e}");
        let dir = tempfile::tempdir().unwrap();
        assert!(write_reconstruction(dir.path(), &rec, true, true).is_err());
    }

    #[test]
    fn imports_every_model() {
        let mut m = ColmapModel::default();
        let cams: [(CameraModel, &[f64]); 5] = [
            (CameraModel::SimplePinhole, &[100.0, 50.5, 40.5]),
            (CameraModel::Pinhole, &[100.0, 200.0, 50.5, 40.5]),
            (CameraModel::SimpleRadial, &[100.0, 50.5, 40.5, 0.25]),
            (CameraModel::Radial, &[100.0, 50.5, 40.5, 0.25, -0.125]),
            (
                CameraModel::Opencv,
                &[100.0, 200.0, 50.5, 40.5, 0.25, -0.125, 0.0, 0.0],
            ),
        ];
        for (i, (model, params)) in cams.iter().enumerate() {
            let id = i as u32;
            m.cameras.insert(
                id,
                ColmapCamera {
                    id,
                    model: *model,
                    width: 101,
                    height: 81,
                    params: params.to_vec(),
                },
            );
        }
        let rec = from_colmap(&m).unwrap();
        let k: Vec<_> = rec.cameras.values().map(|c| c.intrinsics).collect();
        assert_eq!(k[0], Intrinsics::pinhole(100.0, 50.0, 40.0));
        assert_eq!((k[1].aspect, k[1].pp), (2.0, Vector2::new(50.0, 40.0)));
        assert_eq!((k[2].k1, k[2].k2), (0.25, 0.0));
        assert_eq!((k[3].k1, k[3].k2), (0.25, -0.125));
        assert_eq!((k[4].aspect, k[4].k1, k[4].k2), (2.0, 0.25, -0.125));
        m.cameras.get_mut(&4).unwrap().params[7] = 1e-3;
        assert!(from_colmap(&m).unwrap_err().contains("tangential"));
    }

    #[test]
    fn inconsistent_models_are_refused() {
        let mut m = to_colmap(&sample_rec()).unwrap();
        m.points3d.get_mut(&1000).unwrap().track.push((1, 999));
        assert!(from_colmap(&m).is_err());
        let mut m = to_colmap(&sample_rec()).unwrap();
        m.images.get_mut(&1).unwrap().qvec = [0.0; 4];
        assert!(from_colmap(&m).unwrap_err().contains("invalid pose"));
    }
}
