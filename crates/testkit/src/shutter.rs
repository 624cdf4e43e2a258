//! A moving camera's shutter: the rolling read-out and the exposure time (motion blur) of a phone's
//! video, for stress sets that break the global-shutter model the reconstruction assumes.
//!
//! A phone's CMOS sensor reads its rows one after another: row `y` of an image `h` rows high is
//! exposed `readout · ((y + ½)/h − ½)` frame intervals after the middle row, and every row gathers
//! light over the exposure time. The camera moves smoothly through each frame's pose, along the
//! quadratic through its neighbours' (the first and the last frame along the line to their one
//! neighbour), so each ray is cast from the pose of its own time. A frame's ground-truth pose, and its depth map, are its middle row's at mid-exposure:
//! the pose a global-shutter model fitted to the image comes closest to.

use handheld_core::pose::{cam_from_world_from_center, center_of};
use handheld_core::Rigid3;
use nalgebra::UnitQuaternion;

/// The shutter of a synthetic video's frames; the default is a global, instantaneous shutter.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Shutter {
    /// Time from the first row's exposure to the last row's, in frame intervals, in [0, 1]. A
    /// phone's sensor reads a frame out in 0.5–0.9 of a 30 fps frame interval; a video sampled at
    /// every k-th frame has 1/k of that between its frames.
    pub readout: f64,
    /// Exposure time of a row, in frame intervals, in [0, 1]: the motion blur.
    pub exposure: f64,
}

impl Shutter {
    /// Whether every ray of a frame is cast from the frame's own pose.
    pub fn is_global(&self) -> bool {
        self.readout == 0.0 && self.exposure == 0.0
    }

    pub fn validate(&self) -> Result<(), String> {
        for (name, v) in [("readout", self.readout), ("exposure", self.exposure)] {
            if !(0.0..=1.0).contains(&v) {
                return Err(format!(
                    "shutter {name} must be in [0, 1] frame intervals, got {v}"
                ));
            }
        }
        Ok(())
    }

    /// The time (frame intervals from the frame's middle row at mid-exposure) of a ray through
    /// image row `y` (pixels, 0 at the first row's centre; sub-pixel rows allowed) of an image
    /// `height` rows high, in exposure slot `slot` of `slots`.
    pub fn time(&self, y: f64, height: usize, slot: usize, slots: usize) -> f64 {
        let row = (y + 0.5) / height.max(1) as f64 - 0.5;
        let exposure = (slot as f64 + 0.5) / slots.max(1) as f64 - 0.5;
        self.readout * row + self.exposure * exposure
    }
}

/// A frame's pose with its neighbours', between which its camera moves during the frame.
#[derive(Clone, Debug)]
pub struct FrameMotion {
    pub shutter: Shutter,
    pub before: Option<Rigid3>,
    pub at: Rigid3,
    pub after: Option<Rigid3>,
}

impl FrameMotion {
    /// The frame `i` of `poses` (`cam_from_world`) under `shutter`; `None` past the poses.
    pub fn of(poses: &[Rigid3], i: usize, shutter: Shutter) -> Option<Self> {
        Some(Self {
            shutter,
            before: i.checked_sub(1).and_then(|p| poses.get(p)).copied(),
            at: *poses.get(i)?,
            after: poses.get(i + 1).copied(),
        })
    }

    /// `cam_from_world` at `tau` frame intervals from the frame's own time: along the quadratic
    /// through the frame before's, its own and the frame after's poses (the rotation in the
    /// tangent space at the frame's own; linear where a neighbour is missing), so that the camera's
    /// velocity changes smoothly through the frame, as a hand-held camera's does, and equals the
    /// central difference of its neighbours at the frame's time.
    pub fn pose_at(&self, tau: f64) -> Rigid3 {
        let (before, after) = match (self.before, self.after) {
            (Some(b), Some(a)) => (b, a),
            (Some(b), None) => return interpolate(&b, &self.at, 1.0 + tau),
            (None, Some(a)) => return interpolate(&self.at, &a, tau),
            (None, None) => return self.at,
        };
        let q = self.at.rotation;
        let (back, ahead) = (
            (before.rotation * q.inverse()).scaled_axis(),
            (after.rotation * q.inverse()).scaled_axis(),
        );
        let (c, cb, ca) = (center_of(&self.at), center_of(&before), center_of(&after));
        // p(τ) = p₀ + τ (p₊ − p₋)/2 + τ²/2 (p₊ − 2p₀ + p₋), through p₋, p₀, p₊ at τ = −1, 0, 1.
        let (s1, s2) = (0.5 * tau, 0.5 * tau * tau);
        let turn = UnitQuaternion::from_scaled_axis((ahead - back) * s1 + (ahead + back) * s2);
        let centre = c + (ca - cb) * s1 + (ca - c + (cb - c)) * s2;
        cam_from_world_from_center(&(turn * q).inverse().to_rotation_matrix(), &centre)
    }
}

/// The pose a fraction `t` of the way from `a` to `b` (`t` outside [0, 1] extrapolates):
/// the orientation along the geodesic, the centre along the line.
pub fn interpolate(a: &Rigid3, b: &Rigid3, t: f64) -> Rigid3 {
    let (ra, rb) = (a.rotation.inverse(), b.rotation.inverse());
    let step = UnitQuaternion::from_scaled_axis((ra.inverse() * rb).scaled_axis() * t);
    let (ca, cb) = (center_of(a), center_of(b));
    cam_from_world_from_center(&(ra * step).to_rotation_matrix(), &(ca + (cb - ca) * t))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Point3, Rotation3, Vector3};

    fn pose(angle: f64, x: f64) -> Rigid3 {
        cam_from_world_from_center(
            &Rotation3::from_axis_angle(&Vector3::y_axis(), angle),
            &Point3::new(x, 0.0, 0.0),
        )
    }

    #[test]
    fn the_middle_row_at_mid_exposure_is_the_frames_own_pose_and_rows_move_with_the_camera() {
        let poses = [pose(0.0, 0.0), pose(0.1, 1.0), pose(0.2, 2.0)];
        let shutter = Shutter {
            readout: 0.5,
            exposure: 0.2,
        };
        for i in 0..3 {
            let m = FrameMotion::of(&poses, i, shutter).unwrap();
            assert!((m.pose_at(0.0).to_homogeneous() - poses[i].to_homogeneous()).norm() < 1e-12);
            // The last row of an image 100 rows high (its centre 0.495 of the height below the
            // middle), one exposure slot of one: that much of half a frame interval on.
            let tau = shutter.time(99.0, 100, 0, 1);
            assert!((tau - 0.2475).abs() < 1e-12);
            let c = center_of(&m.pose_at(tau));
            assert!((c.x - (i as f64 + tau)).abs() < 1e-12, "frame {i}: {c}");
            let angle = m.pose_at(-tau).rotation.inverse().angle();
            let expected = (0.1 * (i as f64 - tau)).abs();
            assert!((angle - expected).abs() < 1e-12, "frame {i}: {angle}");
        }
        // A jittered frame: the path still passes through its neighbours' poses.
        let jittered = [pose(0.0, 0.0), pose(0.13, 0.8), pose(0.2, 2.1)];
        let m = FrameMotion::of(&jittered, 1, shutter).unwrap();
        for (tau, want) in [(-1.0, jittered[0]), (1.0, jittered[2])] {
            let d = m.pose_at(tau).to_homogeneous() - want.to_homogeneous();
            assert!(d.norm() < 1e-12, "{tau}: {d}");
        }
        assert!(Shutter::default().is_global());
        assert!(Shutter {
            readout: 1.5,
            exposure: 0.0
        }
        .validate()
        .is_err());
    }
}
