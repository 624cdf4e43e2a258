//! Camera paths for fly-throughs: smooth interpolation through recorded poses on SE(3)
//! (Catmull–Rom on the centres, and on the unit quaternions with their signs aligned and
//! renormalised, both C¹), and an orbit around the scene.

use handheld_core::pose::cam_from_world_from_center;
use handheld_core::Rigid3;
use nalgebra::{Matrix3, Point3, Quaternion, Rotation3, UnitQuaternion, Vector3, Vector4};

fn catmull_rom<T>(p0: T, p1: T, p2: T, p3: T, t: f64) -> T
where
    T: std::ops::Mul<f64, Output = T>
        + std::ops::Add<Output = T>
        + std::ops::Sub<Output = T>
        + Copy,
{
    let t2 = t * t;
    let t3 = t2 * t;
    (p1 * 2.0
        + (p2 - p0) * t
        + (p0 * 2.0 - p1 * 5.0 + p2 * 4.0 - p3) * t2
        + (p1 * 3.0 - p0 - p2 * 3.0 + p3) * t3)
        * 0.5
}

/// `frames` poses along a smooth path through `keys` (world → camera), from the first to the last.
pub fn through(keys: &[Rigid3], frames: usize) -> Vec<Rigid3> {
    if keys.is_empty() || frames == 0 {
        return Vec::new();
    }
    if keys.len() == 1 {
        return vec![keys[0]; frames];
    }
    // Camera → world orientations and centres.
    let centres: Vec<Vector3<f64>> = keys
        .iter()
        .map(|k| k.inverse().translation.vector)
        .collect();
    let mut quats: Vec<Vector4<f64>> = Vec::with_capacity(keys.len());
    for k in keys {
        let q = k.rotation.inverse().into_inner().coords;
        let q = match quats.last() {
            Some(prev) if prev.dot(&q) < 0.0 => -q,
            _ => q,
        };
        quats.push(q);
    }
    let n = keys.len();
    let at = |v: &[Vector4<f64>], i: isize| v[i.clamp(0, n as isize - 1) as usize];
    let atc = |v: &[Vector3<f64>], i: isize| v[i.clamp(0, n as isize - 1) as usize];
    (0..frames)
        .map(|f| {
            let s = if frames == 1 {
                0.0
            } else {
                f as f64 * (n - 1) as f64 / (frames - 1) as f64
            };
            let i = (s.floor() as isize).min(n as isize - 2);
            let t = s - i as f64;
            let c = catmull_rom(
                atc(&centres, i - 1),
                atc(&centres, i),
                atc(&centres, i + 1),
                atc(&centres, i + 2),
                t,
            );
            let q = catmull_rom(
                at(&quats, i - 1),
                at(&quats, i),
                at(&quats, i + 1),
                at(&quats, i + 2),
                t,
            );
            let world_from_cam = UnitQuaternion::from_quaternion(Quaternion::from(q));
            cam_from_world_from_center(&world_from_cam.to_rotation_matrix(), &Point3::from(c))
        })
        .collect()
}

/// A camera at `center` looking at `target`, with `up` (world) pointing up in the image.
pub fn look_at(center: &Point3<f64>, target: &Point3<f64>, up: &Vector3<f64>) -> Option<Rigid3> {
    let z = (target - center).try_normalize(1e-12)?;
    let y = -(up - z * up.dot(&z)).try_normalize(1e-9)?;
    let x = y.cross(&z);
    let r = Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[x, y, z]));
    Some(cam_from_world_from_center(&r, center))
}

/// `frames` poses on an orbit around `focus` through the recorded cameras `keys`: in the plane
/// that fits their centres, at their median radius and height, over the arc of azimuths they
/// cover (the whole circle when they surround the scene), looking at `focus`.
pub fn orbit(keys: &[Rigid3], focus: &Point3<f64>, frames: usize) -> Vec<Rigid3> {
    if keys.is_empty() || frames == 0 {
        return Vec::new();
    }
    let centres: Vec<Vector3<f64>> = keys
        .iter()
        .map(|k| k.inverse().translation.vector)
        .collect();
    // The cameras' mean "up" (−y of each camera, in the world).
    let up_mean: Vector3<f64> = keys
        .iter()
        .map(|k| k.rotation.inverse() * Vector3::new(0.0, -1.0, 0.0))
        .sum();
    let mut axis = up_mean.try_normalize(1e-9).unwrap_or(Vector3::y());
    if centres.len() >= 3 {
        let mean = centres.iter().sum::<Vector3<f64>>() / centres.len() as f64;
        let mut cov = Matrix3::zeros();
        for c in &centres {
            cov += (c - mean) * (c - mean).transpose();
        }
        let eig = cov.symmetric_eigen();
        let mut order = [0usize, 1, 2];
        order.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
        // A ring of cameras: its normal is the axis, when the ring is not a line.
        if eig.eigenvalues[order[1]] > 1e-3 * eig.eigenvalues[order[2]] {
            let n = eig.eigenvectors.column(order[0]).into_owned();
            axis = if n.dot(&axis) < 0.0 { -n } else { n };
        }
    }
    let e1 = {
        let v = centres[0] - focus.coords;
        let v = v - axis * v.dot(&axis);
        v.try_normalize(1e-12)
            .unwrap_or_else(|| axis.cross(&Vector3::x()).normalize())
    };
    let e2 = axis.cross(&e1);
    let mut radii = Vec::new();
    let mut heights = Vec::new();
    let mut angles = Vec::new();
    for c in &centres {
        let v = c - focus.coords;
        let h = v.dot(&axis);
        let p = v - axis * h;
        radii.push(p.norm());
        heights.push(h);
        angles.push(p.dot(&e2).atan2(p.dot(&e1)));
    }
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let radius = median(&mut radii);
    let height = median(&mut heights);
    // The covered arc: the circle minus its largest gap between camera azimuths.
    let mut sorted = angles.clone();
    sorted.sort_by(f64::total_cmp);
    let tau = std::f64::consts::TAU;
    let (mut gap, mut start) = (tau - (sorted[sorted.len() - 1] - sorted[0]), sorted[0]);
    for w in sorted.windows(2) {
        if w[1] - w[0] > gap {
            gap = w[1] - w[0];
            start = w[1];
        }
    }
    let span = if gap < tau / 6.0 { tau } else { tau - gap };
    (0..frames)
        .filter_map(|f| {
            let t = if frames == 1 {
                0.5
            } else {
                f as f64 / (frames - 1) as f64
            };
            let a = start + span * t;
            let c = focus.coords + (e1 * a.cos() + e2 * a.sin()) * radius + axis * height;
            look_at(&Point3::from(c), focus, &axis)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The path passes through its keys, and an orbit keeps its radius and looks at the focus.
    #[test]
    fn paths_pass_through_keys_and_orbit_the_focus() {
        let focus = Point3::new(0.0, 0.0, 5.0);
        let keys: Vec<Rigid3> = (0..5)
            .map(|i| {
                let a = i as f64 * 0.3;
                let c = Point3::new(4.0 * a.sin(), -1.0, 5.0 - 4.0 * a.cos());
                look_at(&c, &focus, &Vector3::new(0.0, -1.0, 0.0)).unwrap()
            })
            .collect();
        let path = through(&keys, 9);
        assert_eq!(path.len(), 9);
        for (i, k) in [(0, 0), (2, 1), (8, 4)] {
            let d = path[i].inverse().translation.vector - keys[k].inverse().translation.vector;
            assert!(d.norm() < 1e-9, "{i}: {d}");
            assert!(path[i].rotation.angle_to(&keys[k].rotation) < 1e-9);
        }
        let o = orbit(&keys, &focus, 7);
        assert_eq!(o.len(), 7);
        for p in &o {
            let c = p.inverse().translation.vector;
            let f = p.transform_point(&focus);
            assert!(f.x.abs() < 1e-9 && f.y.abs() < 1e-9 && f.z > 0.0);
            let v = c - focus.coords;
            let r = (v - Vector3::y() * v.y).norm();
            assert!((r - 4.0).abs() < 1e-6, "{r}");
        }
        // The arc spans the keys' azimuths (0 to 1.2 rad), not the whole circle.
        let a = |p: &Rigid3| {
            let v = p.inverse().translation.vector - focus.coords;
            v.x.atan2(-v.z)
        };
        assert!((a(&o[0]) - a(&o[6])).abs() > 1.1 && (a(&o[0]) - a(&o[6])).abs() < 1.3);
    }
}
