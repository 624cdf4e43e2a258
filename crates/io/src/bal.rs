//! Bundle Adjustment in the Large (BAL) problems (Agarwal et al. 2010), the benchmark format of Ceres'
//! `bundle_adjuster`.
//!
//! Text: `<cameras> <points> <observations>`, one line `cam point x y` per observation, then 9 numbers
//! per camera (angle-axis `r`, `t`, `f`, `k1`, `k2`) and 3 per point. BAL projects `P = R(r)·X + t`,
//! `p = −P.xy / P.z`, pixel `= f·(1 + k1‖p‖² + k2‖p‖⁴)·p`, measured from the image centre with y up.
//!
//! [`BalProblem::to_metric_reconstruction`] maps it onto Handheld's camera (looking down +z, y down):
//! with `D = diag(1, −1, −1)` (180° about x), `cam_from_world = (D R, D t)` gives normalised coordinates
//! `(X_c/Z_c, Y_c/Z_c) = (p.x, −p.y)`; the radial factor only sees `‖p‖`, so our pixel (with `pp = 0`,
//! aspect 1, skew 0) is `(u_bal, −v_bal)` and observations become `(x, −y)`. Every residual keeps its
//! norm, so the costs agree.

use std::collections::BTreeMap;
use std::path::Path;

use handheld_core::{
    Camera, CameraId, ImageId, Intrinsics, MetricReconstruction, Observation, Point3D, PointId,
    Rigid3, Track, TrackElement, View,
};
use nalgebra::{Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector2, Vector3};

use crate::error::{IoError, Result};

/// One BAL observation: camera and point indices and the pixel (centre origin, y up).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BalObservation {
    pub camera: usize,
    pub point: usize,
    pub xy: [f64; 2],
}

/// A BAL problem as stored in the file.
#[derive(Clone, Debug, PartialEq)]
pub struct BalProblem {
    /// Per camera: angle-axis `r` (3), `t` (3), `f`, `k1`, `k2`.
    pub cameras: Vec<[f64; 9]>,
    pub points: Vec<[f64; 3]>,
    pub observations: Vec<BalObservation>,
}

/// Reads a BAL text file. Errors name the file and the line.
pub fn read_bal(path: &Path) -> Result<BalProblem> {
    let text = std::fs::read_to_string(path).map_err(|e| IoError::io(path, e))?;
    parse_bal(&text)
        .map_err(|(line, reason)| IoError::format(path, format!("line {line}: {reason}")))
}

/// Parses BAL text; errors are `(line number, reason)`.
pub fn parse_bal(text: &str) -> std::result::Result<BalProblem, (usize, String)> {
    let mut tokens = text
        .lines()
        .enumerate()
        .flat_map(|(i, l)| l.split_whitespace().map(move |t| (i + 1, t)));
    let mut last_line = 1;
    let mut next = |what: &str| -> std::result::Result<(usize, &str), (usize, String)> {
        let r = tokens.next().ok_or((
            last_line,
            format!("unexpected end of file, expected {what}"),
        ));
        if let Ok((l, _)) = r {
            last_line = l;
        }
        r
    };
    fn num<T: std::str::FromStr>(
        (line, t): (usize, &str),
        what: &str,
    ) -> std::result::Result<T, (usize, String)> {
        t.parse::<T>()
            .map_err(|_| (line, format!("{what} `{t}` is not a valid number")))
    }
    let nc: usize = num(next("the camera count")?, "camera count")?;
    let np: usize = num(next("the point count")?, "point count")?;
    let no: usize = num(next("the observation count")?, "observation count")?;
    const LIMIT: usize = 1 << 28;
    if nc > LIMIT || np > LIMIT || no > LIMIT {
        return Err((1, format!("implausible sizes {nc} {np} {no}")));
    }
    let mut observations = Vec::with_capacity(no);
    for _ in 0..no {
        let tc = next("an observation")?;
        let camera: usize = num(tc, "camera index")?;
        let point: usize = num(next("a point index")?, "point index")?;
        if camera >= nc || point >= np {
            return Err((tc.0, format!("observation of camera {camera} / point {point} out of range ({nc} cameras, {np} points)")));
        }
        let x: f64 = num(next("x")?, "x")?;
        let y: f64 = num(next("y")?, "y")?;
        observations.push(BalObservation {
            camera,
            point,
            xy: [x, y],
        });
    }
    let mut cameras = Vec::with_capacity(nc);
    for _ in 0..nc {
        let mut c = [0.0; 9];
        for v in c.iter_mut() {
            *v = num(next("a camera parameter")?, "camera parameter")?;
        }
        cameras.push(c);
    }
    let mut points = Vec::with_capacity(np);
    for _ in 0..np {
        let mut p = [0.0; 3];
        for v in p.iter_mut() {
            *v = num(next("a point coordinate")?, "point coordinate")?;
        }
        points.push(p);
    }
    Ok(BalProblem {
        cameras,
        points,
        observations,
    })
}

/// Rotation matrix of an angle-axis vector (Rodrigues).
pub fn angle_axis_matrix(r: &[f64]) -> Matrix3<f64> {
    Rotation3::from_scaled_axis(Vector3::new(r[0], r[1], r[2])).into_inner()
}

impl BalProblem {
    /// BAL's own residual (pixels, y up) of observation `o`.
    pub fn residual(&self, o: usize) -> [f64; 2] {
        let ob = &self.observations[o];
        let c = &self.cameras[ob.camera];
        let x = &self.points[ob.point];
        let p = angle_axis_matrix(&c[..3]) * Vector3::new(x[0], x[1], x[2])
            + Vector3::new(c[3], c[4], c[5]);
        let (px, py) = (-p.x / p.z, -p.y / p.z);
        let r2 = px * px + py * py;
        let d = c[6] * (1.0 + c[7] * r2 + c[8] * r2 * r2);
        [d * px - ob.xy[0], d * py - ob.xy[1]]
    }

    /// Ceres' cost `½ Σ ‖r‖²` with BAL's projection.
    pub fn cost(&self) -> f64 {
        0.5 * (0..self.observations.len())
            .map(|o| self.residual(o))
            .map(|r| r[0] * r[0] + r[1] * r[1])
            .sum::<f64>()
    }

    /// The same problem as a metric reconstruction (see the module doc): camera `i` becomes intrinsics
    /// group `CameraId(i)` (its own `f`, `k1`, `k2`; aspect 1, skew 0, principal point 0) and view
    /// `ImageId(i)`; point `j` becomes `PointId(j)`.
    pub fn to_metric_reconstruction(&self) -> MetricReconstruction {
        let mut rec = MetricReconstruction::default();
        let d = Matrix3::from_diagonal(&Vector3::new(1.0, -1.0, -1.0));
        for (i, c) in self.cameras.iter().enumerate() {
            let id = CameraId(i as u32);
            let k = Intrinsics {
                f: c[6],
                aspect: 1.0,
                skew: 0.0,
                pp: Vector2::zeros(),
                k1: c[7],
                k2: c[8],
            };
            rec.cameras.insert(
                id,
                Camera {
                    id,
                    width: 0,
                    height: 0,
                    intrinsics: k,
                },
            );
            let r = d * angle_axis_matrix(&c[..3]);
            let t = d * Vector3::new(c[3], c[4], c[5]);
            let q = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r));
            let pose = Rigid3::from_parts(Translation3::from(t), q);
            let image = ImageId(i as u32);
            rec.views.insert(
                image,
                View {
                    id: image,
                    name: format!("bal_{i}"),
                    camera_id: id,
                    cam_from_world: pose,
                    observations: Vec::new(),
                    frame: None,
                },
            );
        }
        let mut tracks: BTreeMap<usize, Vec<TrackElement>> = BTreeMap::new();
        for ob in &self.observations {
            let image = ImageId(ob.camera as u32);
            if let Some(v) = rec.views.get_mut(&image) {
                tracks.entry(ob.point).or_default().push(TrackElement {
                    image_id: image,
                    point2d_idx: v.observations.len() as u32,
                });
                v.observations.push(Observation {
                    xy: Vector2::new(ob.xy[0], -ob.xy[1]),
                    point_id: Some(PointId(ob.point as u64)),
                });
            }
        }
        for (j, x) in self.points.iter().enumerate() {
            let elements = tracks.remove(&j).unwrap_or_default();
            rec.points.insert(
                PointId(j as u64),
                Point3D {
                    xyz: Point3::new(x[0], x[1], x[2]),
                    color: [128; 3],
                    error: -1.0,
                    track: Track { elements },
                },
            );
        }
        rec
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const TINY: &str = "2 2 3\n0 0 1.5 -2.0\n1 0 0.5 1.0\n1 1 -3.0 2.5\n\
        0.01 -0.02 0.03 0.1 0.2 -5.0 500.0 -0.1 0.01\n\
        -0.05 0.04 0.02 -0.3 0.1 -6.0 520.0 0.05 -0.02\n\
        0.1 0.2 0.3\n-0.4 0.5 0.6\n";

    #[test]
    fn parses_and_converted_cost_matches_bal_formula() {
        let bal = parse_bal(TINY).expect("valid");
        assert_eq!(
            (bal.cameras.len(), bal.points.len(), bal.observations.len()),
            (2, 2, 3)
        );
        let rec = bal.to_metric_reconstruction();
        rec.validate().expect("consistent");
        let mut ours = 0.0;
        for p in rec.points.values() {
            for el in &p.track.elements {
                let v = &rec.views[&el.image_id];
                let px = rec.cameras[&v.camera_id]
                    .project(&v.cam_from_world, &p.xyz)
                    .expect("in front");
                ours += 0.5 * (px - v.observations[el.point2d_idx as usize].xy).norm_squared();
            }
        }
        let theirs = bal.cost();
        assert!(
            (ours - theirs).abs() <= 1e-12 * theirs,
            "{ours} vs {theirs}"
        );
    }

    #[test]
    fn errors_name_the_line() {
        let err = parse_bal("1 1 1\n0 0 1.0 x\n").unwrap_err();
        assert_eq!(err.0, 2, "{err:?}");
        let err = parse_bal("1 1 1\n0 3 1.0 2.0\n").unwrap_err();
        assert!(err.1.contains("out of range"), "{err:?}");
        let err = parse_bal("1 1 1\n0 0 1.0 2.0\n1 2 3\n").unwrap_err();
        assert!(err.1.contains("end of file"), "{err:?}");
    }
}
