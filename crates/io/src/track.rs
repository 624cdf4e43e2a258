//! A camera track for the tools people use (§5.3's match-moving):
//! - binary glTF 2.0 with one animated camera (translation and rotation channels, one key per
//!   frame at `time = frame / fps`, linear interpolation) and the sparse points as a point cloud
//!   (a `POINTS` primitive with `COLOR_0`), for Blender, three.js and most DCC tools;
//! - a Nuke `.chan` file: one line per frame.
//!
//! Axis conventions. Handheld's cameras look down +Z with +Y down (`p_cam = R·p + t`). glTF and
//! Nuke cameras look down −Z with +Y up, so a glTF/Nuke camera's orientation in the world is
//! `R_world_from_cam · diag(1, −1, −1)`. The world frame is the sparse model's, unchanged. Both
//! files store the camera's pose in the world (where it is and how it turns), not the
//! world → camera transform.
//!
//! glTF animation outputs are 32-bit floats; to keep them precise far from the origin, the
//! camera and the points hang under a root node whose translation (written in the JSON, full
//! precision) is the cameras' mean centre.

use std::path::Path;

use handheld_core::{Camera, PosedCamera, Rigid3};
use nalgebra::{Matrix3, Rotation3, UnitQuaternion, Vector3};
use serde_json::json;

use crate::atomic::write_bytes_atomic;
use crate::error::{IoError, Result};
use crate::glb::{container, Bin};

const UNSIGNED_BYTE: u32 = 5121;
const ARRAY_BUFFER: u32 = 34962;

/// One frame of a track.
///
/// Not a [`PosedCamera`]: the track files (glTF animation, Nuke `.chan`) key one shared camera's
/// pose by frame number and time, so a frame carries those two and the pose, and the camera is
/// given once for the whole track ([`write_chan`]'s field of view). [`TrackFrame::to_posed`]
/// attaches a camera.
#[derive(Clone, Copy, Debug)]
pub struct TrackFrame {
    /// The frame's number in the video (Nuke's frame column).
    pub frame: u64,
    /// Seconds from the start (glTF's key time).
    pub time_s: f64,
    pub cam_from_world: Rigid3,
}

impl TrackFrame {
    /// The frame's pose with `camera`.
    pub fn to_posed(&self, camera: Camera) -> PosedCamera {
        PosedCamera::new(camera, self.cam_from_world)
    }
}

/// The flip between Handheld's camera axes and glTF's / Nuke's (+Y up, looking down −Z).
fn flip() -> Matrix3<f64> {
    Matrix3::from_diagonal(&Vector3::new(1.0, -1.0, -1.0))
}

/// A glTF/Nuke camera's orientation in the world and its centre.
pub fn camera_in_world(cam_from_world: &Rigid3) -> (UnitQuaternion<f64>, Vector3<f64>) {
    let r_wc = cam_from_world.rotation.inverse().to_rotation_matrix();
    let r = Rotation3::from_matrix_unchecked(r_wc.matrix() * flip());
    let centre = cam_from_world.inverse().translation.vector;
    (UnitQuaternion::from_rotation_matrix(&r), centre)
}

/// The inverse of [`camera_in_world`]: Handheld's world → camera from a glTF/Nuke camera.
pub fn cam_from_world_of(orientation: &UnitQuaternion<f64>, centre: &Vector3<f64>) -> Rigid3 {
    let r_wc = orientation.to_rotation_matrix().matrix() * flip();
    let r = Rotation3::from_matrix_unchecked(r_wc.transpose());
    handheld_core::pose::cam_from_world_from_center(&r.inverse(), &(*centre).into())
}

/// Writes the track as a `.glb`: `yfov` (radians) and `aspect` (width / height) describe the
/// camera; `points` (model frame, with colours) become a point cloud. Errors name `path`.
pub fn write_track_glb(
    path: &Path,
    frames: &[TrackFrame],
    yfov: f64,
    aspect: f64,
    points: &[([f64; 3], [u8; 3])],
) -> Result<()> {
    if frames.is_empty() {
        return Err(IoError::format(
            path,
            "a camera track needs at least one frame",
        ));
    }
    let poses: Vec<(UnitQuaternion<f64>, Vector3<f64>)> = frames
        .iter()
        .map(|f| camera_in_world(&f.cam_from_world))
        .collect();
    let origin = poses.iter().map(|p| p.1).sum::<Vector3<f64>>() / poses.len() as f64;
    let mut bin = Bin::default();
    let times: Vec<f32> = frames.iter().map(|f| f.time_s as f32).collect();
    let t_acc = bin.floats_for(&times, 1, "SCALAR", true, None);
    let translations: Vec<f32> = poses
        .iter()
        .flat_map(|(_, c)| {
            let d = c - origin;
            [d.x as f32, d.y as f32, d.z as f32]
        })
        .collect();
    let tr_acc = bin.floats_for(&translations, 3, "VEC3", false, None);
    let rotations: Vec<f32> = poses
        .iter()
        .flat_map(|(q, _)| {
            let q = q.into_inner();
            [q.i as f32, q.j as f32, q.k as f32, q.w as f32]
        })
        .collect();
    let rot_acc = bin.floats_for(&rotations, 4, "VEC4", false, None);
    let (q0, c0) = poses[0];
    let d0 = c0 - origin;
    let mut nodes = vec![
        json!({"name": "model", "translation": [origin.x, origin.y, origin.z], "children": [1]}),
        json!({
            "name": "camera",
            "camera": 0,
            "translation": [d0.x, d0.y, d0.z],
            "rotation": [q0.i, q0.j, q0.k, q0.w],
        }),
    ];
    let mut meshes = Vec::new();
    if !points.is_empty() {
        let rel: Vec<f32> = points
            .iter()
            .flat_map(|(p, _)| {
                [
                    (p[0] - origin.x) as f32,
                    (p[1] - origin.y) as f32,
                    (p[2] - origin.z) as f32,
                ]
            })
            .collect();
        let pos = bin.floats(&rel, 3, "VEC3", true);
        let colours: Vec<u8> = points
            .iter()
            .flat_map(|(_, c)| [c[0], c[1], c[2], 255])
            .collect();
        let view = bin.view(&colours, Some(ARRAY_BUFFER), None);
        bin.accessors.push(json!({
            "bufferView": view, "componentType": UNSIGNED_BYTE, "normalized": true,
            "count": points.len(), "type": "VEC4"
        }));
        let col = bin.accessors.len() - 1;
        meshes.push(json!({
            "name": "sparse points",
            "primitives": [{"attributes": {"POSITION": pos, "COLOR_0": col}, "mode": 0}],
        }));
        nodes.push(json!({"name": "points", "mesh": 0}));
        nodes[0]["children"] = json!([1, 2]);
    }
    let mut doc = json!({
        "asset": {"version": "2.0", "generator": "handheld (camera track)"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": nodes,
        "cameras": [{
            "type": "perspective",
            "perspective": {"yfov": yfov, "aspectRatio": aspect, "znear": 0.01},
        }],
        "animations": [{
            "name": "camera track",
            "samplers": [
                {"input": t_acc, "output": tr_acc, "interpolation": "LINEAR"},
                {"input": t_acc, "output": rot_acc, "interpolation": "LINEAR"},
            ],
            "channels": [
                {"sampler": 0, "target": {"node": 1, "path": "translation"}},
                {"sampler": 1, "target": {"node": 1, "path": "rotation"}},
            ],
        }],
    });
    if !meshes.is_empty() {
        doc["meshes"] = json!(meshes);
    }
    write_bytes_atomic(path, &container(path, doc, bin)?)
}

/// Nuke's camera rotation order ZXY: `R_world_from_cam = Ry(ry) · Rx(rx) · Rz(rz)`; returns
/// (rx, ry, rz) in degrees.
pub fn euler_zxy_deg(r: &Matrix3<f64>) -> [f64; 3] {
    // R = Ry Rx Rz: r[1][2] = −sin(rx).
    let rx = (-r[(1, 2)]).clamp(-1.0, 1.0).asin();
    let (ry, rz) = if rx.cos().abs() > 1e-9 {
        (r[(0, 2)].atan2(r[(2, 2)]), r[(1, 0)].atan2(r[(1, 1)]))
    } else {
        // Gimbal lock: fold everything into ry.
        ((-r[(2, 0)]).atan2(r[(0, 0)]), 0.0)
    };
    [rx.to_degrees(), ry.to_degrees(), rz.to_degrees()]
}

/// The rotation of [`euler_zxy_deg`]'s angles.
pub fn rotation_zxy_deg(a: [f64; 3]) -> Matrix3<f64> {
    let [rx, ry, rz] = a.map(f64::to_radians);
    let x = Rotation3::from_axis_angle(&Vector3::x_axis(), rx);
    let y = Rotation3::from_axis_angle(&Vector3::y_axis(), ry);
    let z = Rotation3::from_axis_angle(&Vector3::z_axis(), rz);
    *(y * x * z).matrix()
}

/// Writes a Nuke `.chan` file: per frame `frame tx ty tz rx ry rz vfov` (the camera's centre,
/// its ZXY Euler angles in degrees, the vertical field of view in degrees), one line per frame.
pub fn write_chan(path: &Path, frames: &[TrackFrame], vfov_deg: f64) -> Result<()> {
    let mut text = String::new();
    for f in frames {
        let (q, c) = camera_in_world(&f.cam_from_world);
        let [rx, ry, rz] = euler_zxy_deg(q.to_rotation_matrix().matrix());
        text.push_str(&format!(
            "{} {:.9} {:.9} {:.9} {:.9} {:.9} {:.9} {:.6}\n",
            f.frame, c.x, c.y, c.z, rx, ry, rz, vfov_deg
        ));
    }
    write_bytes_atomic(path, text.as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Point3, Translation3};

    fn pose(a: f64) -> Rigid3 {
        let r = UnitQuaternion::from_euler_angles(0.3 * a, -0.7 + a, 0.2);
        Rigid3::from_parts(Translation3::new(1.0 + a, -2.0, 30.0 * a), r)
    }

    /// The glTF camera's axes and the Euler angles round-trip; a glTF camera looks down −Z.
    #[test]
    fn conventions_round_trip() {
        for a in [0.0, 0.4, 1.3] {
            let p = pose(a);
            let (q, c) = camera_in_world(&p);
            let back = cam_from_world_of(&q, &c);
            assert!((back.to_homogeneous() - p.to_homogeneous()).norm() < 1e-12);
            // −Z of the glTF camera is +Z of ours: a point ahead of us is ahead of it.
            let ahead = p.inverse().transform_point(&Point3::new(0.0, 0.0, 5.0));
            let in_gltf = q.inverse() * (ahead.coords - c);
            assert!((in_gltf - Vector3::new(0.0, 0.0, -5.0)).norm() < 1e-9);
            let m = q.to_rotation_matrix();
            let e = euler_zxy_deg(m.matrix());
            assert!((rotation_zxy_deg(e) - m.matrix()).norm() < 1e-9);
        }
    }

    /// The .glb loads with the `gltf` crate; its camera, sampled at each frame's time, gives our
    /// camera back to 1e-6 (relative to the scene's size); the .chan has one line per frame and
    /// gives the same cameras.
    #[test]
    fn exported_track_reproduces_the_cameras() {
        let dir = tempfile::tempdir().unwrap();
        let frames: Vec<TrackFrame> = (0..25)
            .map(|k| TrackFrame {
                frame: 100 + k,
                time_s: k as f64 / 29.97,
                cam_from_world: pose(k as f64 * 0.05),
            })
            .collect();
        let points = vec![
            ([1.0, 2.0, 3.0], [255, 0, 0]),
            ([40.0, -2.0, 8.0], [0, 255, 0]),
        ];
        let glb = dir.path().join("track.glb");
        write_track_glb(&glb, &frames, 0.8, 1.5, &points).unwrap();
        let (doc, buffers, _) = gltf::import(&glb).expect("a valid glTF");
        let root = doc.default_scene().unwrap().nodes().next().unwrap();
        let cam = doc.nodes().find(|n| n.camera().is_some()).unwrap();
        let offset = Vector3::from(root.transform().decomposed().0).cast::<f64>();
        let anim = doc.animations().next().unwrap();
        let mut times = Vec::new();
        let mut trans = Vec::new();
        let mut rots = Vec::new();
        for ch in anim.channels() {
            assert_eq!(ch.target().node().index(), cam.index());
            let r = ch.reader(|b| Some(&buffers[b.index()]));
            times = r.read_inputs().unwrap().collect();
            match r.read_outputs().unwrap() {
                gltf::animation::util::ReadOutputs::Translations(t) => trans = t.collect(),
                gltf::animation::util::ReadOutputs::Rotations(q) => rots = q.into_f32().collect(),
                _ => panic!("unexpected channel"),
            }
        }
        assert_eq!(times.len(), frames.len());
        let scale = 1.0
            + frames
                .iter()
                .map(|f| f.cam_from_world.inverse().translation.vector.norm())
                .fold(0.0, f64::max);
        for (k, f) in frames.iter().enumerate() {
            assert!((f64::from(times[k]) - f.time_s).abs() < 1e-6);
            let t = Vector3::from(trans[k]).cast::<f64>() + offset;
            let q = rots[k];
            let q = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
                f64::from(q[3]),
                f64::from(q[0]),
                f64::from(q[1]),
                f64::from(q[2]),
            ));
            let back = cam_from_world_of(&q, &t);
            let (qa, ca) = camera_in_world(&f.cam_from_world);
            assert!(
                (t - ca).norm() < 1e-6 * scale,
                "frame {k}: {}",
                (t - ca).norm()
            );
            assert!(q.angle_to(&qa) < 1e-6, "frame {k}: {}", q.angle_to(&qa));
            assert!(
                (back.translation.vector - f.cam_from_world.translation.vector).norm()
                    < 1e-6 * scale
            );
        }
        let chan = dir.path().join("track.chan");
        write_chan(&chan, &frames, 45.0).unwrap();
        let text = std::fs::read_to_string(&chan).unwrap();
        assert_eq!(text.lines().count(), frames.len());
        for (line, f) in text.lines().zip(&frames) {
            let v: Vec<f64> = line
                .split_whitespace()
                .map(|x| x.parse().unwrap())
                .collect();
            assert_eq!(v.len(), 8);
            assert_eq!(v[0] as u64, f.frame);
            let r = rotation_zxy_deg([v[4], v[5], v[6]]);
            let (qa, ca) = camera_in_world(&f.cam_from_world);
            assert!((Vector3::new(v[1], v[2], v[3]) - ca).norm() < 1e-6 * scale);
            assert!((r - qa.to_rotation_matrix().matrix()).norm() < 1e-6);
        }
    }
}
