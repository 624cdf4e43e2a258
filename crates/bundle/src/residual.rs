//! One small residual function per camera model, with analytic Jacobians, and the manifold updates of
//! the parameter blocks.
//!
//! - **Metric** (§3.4, eqs. 2–3): `X_c = R X + t`, `x = X_c.xy / X_c.z`, `x_d = (1 + k1ρ² + k2ρ⁴) x`,
//!   `u = f x_d + s y_d + u₀`, `v = r f y_d + v₀`. The rotation is updated on the left,
//!   `R ← exp([δ]×) R` (local angle-axis), the translation, point and intrinsics additively.
//!   Intrinsics are ordered `[f, aspect, skew, u₀, v₀, k1, k2, ρx, ρy]`.
//! - **Rolling shutter** (a phone's video; Hedborg et al., *Rolling shutter bundle adjustment*, CVPR
//!   2012, with Klingner et al.'s velocity from the neighbouring frames, ICCV 2013): an
//!   observation at pixel `(u, v)` of an image `w × h` was read out `τ = ρx (u/w − ½) + ρy (v/h − ½)`
//!   frame intervals after the image centre, when the camera had moved on by `τ` times its velocity
//!   `(ω, ν)` (per frame interval, in the camera frame): `X_c = (I + τ[ω]×) R X + t + τ ν`, to first
//!   order in `τ ω`. The velocity is a constant of the adjustment ([`Motion`]); `ρx, ρy` (the
//!   group's read-out across the image, along each axis) are intrinsics. Without a velocity the
//!   model is the global-shutter one.
//! - **Projective** (§3.3, eq. 1): `m = P X`, pixel `= m.xy / m.z`. `P` (12-vector) and `X` (4-vector)
//!   live on unit spheres; the local update is `v ← (v + B δ)/‖·‖` with `B` the orthonormal tangent
//!   basis given by a Householder reflection (as Ceres' `SphereManifold`).
//!
//! Jacobians are stored column by column (`[∂r₀, ∂r₁]` per parameter), the residual is
//! `predicted − observed` in pixels.

use nalgebra::{Matrix3, Vector3};

/// Number of intrinsic parameters of the metric model.
pub const NUM_INTRINSICS: usize = 9;

/// An observation's rolling-shutter motion (module notes): its camera's velocity `[ω, ν]` per frame
/// interval and its read-out basis `[u/w − ½, v/h − ½]`. The default is a still camera.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Motion {
    pub velocity: [f64; 6],
    pub basis: [f64; 2],
}

impl Motion {
    /// The read-out time `τ` of the observation under intrinsics `intr`, and `X_c`'s velocity
    /// `ω × R X + ν` at `rx = R X`.
    #[inline]
    fn at(&self, intr: &[f64; NUM_INTRINSICS], rx: &Vector3<f64>) -> (f64, Vector3<f64>) {
        let v = &self.velocity;
        // A still camera (every photo): nothing to add, at no cost in the innermost loop.
        if *v == [0.0; 6] {
            return (0.0, Vector3::zeros());
        }
        let w = Vector3::new(v[0], v[1], v[2]);
        let tau = intr[7] * self.basis[0] + intr[8] * self.basis[1];
        (tau, w.cross(rx) + Vector3::new(v[3], v[4], v[5]))
    }
}

/// Metric camera block: rotation `R` row-major (9 values) then translation `t` (`cam_from_world`).
pub type PoseBlock = [f64; 12];

#[inline]
fn rot(cam: &PoseBlock) -> Matrix3<f64> {
    Matrix3::new(
        cam[0], cam[1], cam[2], cam[3], cam[4], cam[5], cam[6], cam[7], cam[8],
    )
}

/// Residual of the metric model.
#[inline]
pub fn metric_residual(
    cam: &PoseBlock,
    intr: &[f64; NUM_INTRINSICS],
    x: &[f64; 4],
    obs: [f64; 2],
    motion: &Motion,
) -> [f64; 2] {
    let rx = rot(cam) * Vector3::new(x[0], x[1], x[2]);
    let (tau, moving) = motion.at(intr, &rx);
    let xc = rx + Vector3::new(cam[9], cam[10], cam[11]) + tau * moving;
    let (nx, ny) = (xc.x / xc.z, xc.y / xc.z);
    let r2 = nx * nx + ny * ny;
    let d = 1.0 + intr[5] * r2 + intr[6] * r2 * r2;
    let (xd, yd) = (nx * d, ny * d);
    [
        intr[0] * xd + intr[2] * yd + intr[3] - obs[0],
        intr[1] * intr[0] * yd + intr[4] - obs[1],
    ]
}

/// Residual of the metric model and its Jacobians: `jpose` w.r.t. (local rotation δ, t), `jintr` w.r.t.
/// the intrinsics and `jpt` w.r.t. the point (the velocity held: module notes).
#[inline]
#[allow(clippy::too_many_arguments)] // the innermost kernel: its outputs are written in place
pub fn metric_jacobian(
    cam: &PoseBlock,
    intr: &[f64; NUM_INTRINSICS],
    x: &[f64; 4],
    obs: [f64; 2],
    motion: &Motion,
    jpose: &mut [[f64; 2]; 6],
    jintr: &mut [[f64; 2]; NUM_INTRINSICS],
    jpt: &mut [[f64; 2]; 3],
) -> [f64; 2] {
    // A still camera (every photo) gets the kernel without the rolling-shutter terms.
    if motion.velocity == [0.0; 6] {
        jacobian::<false>(cam, intr, x, obs, motion, jpose, jintr, jpt)
    } else {
        jacobian::<true>(cam, intr, x, obs, motion, jpose, jintr, jpt)
    }
}

#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn jacobian<const ROLLING: bool>(
    cam: &PoseBlock,
    intr: &[f64; NUM_INTRINSICS],
    x: &[f64; 4],
    obs: [f64; 2],
    motion: &Motion,
    jpose: &mut [[f64; 2]; 6],
    jintr: &mut [[f64; 2]; NUM_INTRINSICS],
    jpt: &mut [[f64; 2]; 3],
) -> [f64; 2] {
    let r = rot(cam);
    let rx = r * Vector3::new(x[0], x[1], x[2]);
    let (tau, moving) = if ROLLING {
        motion.at(intr, &rx)
    } else {
        (0.0, Vector3::zeros())
    };
    let xc = if ROLLING {
        rx + Vector3::new(cam[9], cam[10], cam[11]) + tau * moving
    } else {
        rx + Vector3::new(cam[9], cam[10], cam[11])
    };
    // `(I + τ[ω]×) v` for the rotation's and the point's columns.
    let tw = tau * Vector3::new(motion.velocity[0], motion.velocity[1], motion.velocity[2]);
    let turn = |v: Vector3<f64>| if ROLLING { v + tw.cross(&v) } else { v };
    let iz = 1.0 / xc.z;
    let (nx, ny) = (xc.x * iz, xc.y * iz);
    let r2 = nx * nx + ny * ny;
    let (k1, k2) = (intr[5], intr[6]);
    let d = 1.0 + k1 * r2 + k2 * r2 * r2;
    let (xd, yd) = (nx * d, ny * d);
    let (f, a, s) = (intr[0], intr[1], intr[2]);
    let fy = a * f;
    let res = [
        f * xd + s * yd + intr[3] - obs[0],
        fy * yd + intr[4] - obs[1],
    ];
    // ∂(xd, yd)/∂(x, y) = d I + 2 (k1 + 2 k2 r²) [x y]ᵀ[x y].
    let c = 2.0 * (k1 + 2.0 * k2 * r2);
    let (b00, b01, b11) = (d + c * nx * nx, c * nx * ny, d + c * ny * ny);
    // A·B with A = [[f, s], [0, fy]].
    let (m00, m01) = (f * b00 + s * b01, f * b01 + s * b11);
    let (m10, m11) = (fy * b01, fy * b11);
    // ∂(x, y)/∂X_c = [[iz, 0, −x iz], [0, iz, −y iz]].
    let jxc = [
        [m00 * iz, m10 * iz],
        [m01 * iz, m11 * iz],
        [-(m00 * nx + m01 * ny) * iz, -(m10 * nx + m11 * ny) * iz],
    ];
    let through = |v: Vector3<f64>| {
        [
            jxc[0][0] * v.x + jxc[1][0] * v.y + jxc[2][0] * v.z,
            jxc[0][1] * v.x + jxc[1][1] * v.y + jxc[2][1] * v.z,
        ]
    };
    for k in 0..3 {
        // Rotation: ∂X_c/∂δ = −(I + τ[ω]×)[R X]×, whose column k is (I + τ[ω]×)(e_k × R X).
        jpose[k] = through(turn(Vector3::ith(k, 1.0).cross(&rx)));
        jpose[3 + k] = jxc[k];
        // Point: ∂X_c/∂X = (I + τ[ω]×) R, column k of R turned.
        jpt[k] = through(turn(r.column(k).into_owned()));
    }
    jintr[0] = [xd, a * yd];
    jintr[1] = [0.0, f * yd];
    jintr[2] = [yd, 0.0];
    jintr[3] = [1.0, 0.0];
    jintr[4] = [0.0, 1.0];
    // ∂(u, v)/∂k = A · [x, y] · r^(2j).
    let (ax, ay) = (f * nx + s * ny, fy * ny);
    jintr[5] = [ax * r2, ay * r2];
    jintr[6] = [ax * r2 * r2, ay * r2 * r2];
    // Read-out: ∂X_c/∂ρ = basis · (ω × R X + ν).
    if ROLLING {
        let dm = through(moving);
        jintr[7] = [dm[0] * motion.basis[0], dm[1] * motion.basis[0]];
        jintr[8] = [dm[0] * motion.basis[1], dm[1] * motion.basis[1]];
    } else {
        (jintr[7], jintr[8]) = ([0.0; 2], [0.0; 2]);
    }
    res
}

/// Residual of the projective model (`P` row-major).
#[inline]
pub fn projective_residual(p: &[f64; 12], x: &[f64; 4], obs: [f64; 2]) -> [f64; 2] {
    let m = |i: usize| {
        p[4 * i] * x[0] + p[4 * i + 1] * x[1] + p[4 * i + 2] * x[2] + p[4 * i + 3] * x[3]
    };
    let (m0, m1, m2) = (m(0), m(1), m(2));
    [m0 / m2 - obs[0], m1 / m2 - obs[1]]
}

/// Residual of the projective model and its Jacobians in the local (tangent) coordinates of `P`
/// (11 columns) and `X` (3 columns).
#[inline]
pub fn projective_jacobian(
    p: &[f64; 12],
    x: &[f64; 4],
    obs: [f64; 2],
    jcam: &mut [[f64; 2]; 11],
    jpt: &mut [[f64; 2]; 3],
) -> [f64; 2] {
    let m = |i: usize| {
        p[4 * i] * x[0] + p[4 * i + 1] * x[1] + p[4 * i + 2] * x[2] + p[4 * i + 3] * x[3]
    };
    let (m0, m1, m2) = (m(0), m(1), m(2));
    let iw = 1.0 / m2;
    let (u, v) = (m0 * iw, m1 * iw);
    // E = ∂(u, v)/∂m = [[iw, 0, −u iw], [0, iw, −v iw]].
    let e = [[iw, 0.0], [0.0, iw], [-u * iw, -v * iw]];
    let mut jp = [[0.0; 2]; 12];
    for i in 0..3 {
        for j in 0..4 {
            jp[4 * i + j] = [e[i][0] * x[j], e[i][1] * x[j]];
        }
    }
    let mut jx = [[0.0; 2]; 4];
    for (j, c) in jx.iter_mut().enumerate() {
        for i in 0..3 {
            c[0] += e[i][0] * p[4 * i + j];
            c[1] += e[i][1] * p[4 * i + j];
        }
    }
    Householder::new(p).jacobian_times_basis(&jp, jcam);
    Householder::new(x).jacobian_times_basis(&jx, jpt);
    [u - obs[0], v - obs[1]]
}

/// The Householder reflection `H = I − β u uᵀ` mapping `v` to a multiple of the last axis; its first
/// `N − 1` columns are an orthonormal basis `B` of the tangent space of the sphere at `v`.
#[derive(Clone, Copy, Debug)]
pub struct Householder<const N: usize> {
    u: [f64; N],
    beta: f64,
}

impl<const N: usize> Householder<N> {
    pub fn new(v: &[f64; N]) -> Self {
        let n = v.iter().map(|a| a * a).sum::<f64>().sqrt();
        let mut u = *v;
        u[N - 1] += if v[N - 1] >= 0.0 { n } else { -n };
        let uu: f64 = u.iter().map(|a| a * a).sum();
        Self {
            u,
            beta: if uu > 0.0 { 2.0 / uu } else { 0.0 },
        }
    }

    /// `B δ` for a tangent vector `δ` of length `N − 1`.
    pub fn apply(&self, delta: &[f64]) -> [f64; N] {
        let mut out = [0.0; N];
        out[..N - 1].copy_from_slice(&delta[..N - 1]);
        let ud: f64 = self.u[..N - 1].iter().zip(delta).map(|(a, b)| a * b).sum();
        for (o, ui) in out.iter_mut().zip(&self.u) {
            *o -= self.beta * ud * ui;
        }
        out
    }

    /// Columns of `J B` from the ambient columns of `J`.
    pub fn jacobian_times_basis(&self, j: &[[f64; 2]; N], out: &mut [[f64; 2]]) {
        let mut ju = [0.0; 2];
        for (c, ui) in j.iter().zip(&self.u) {
            ju[0] += c[0] * ui;
            ju[1] += c[1] * ui;
        }
        for k in 0..N - 1 {
            out[k] = [
                j[k][0] - self.beta * ju[0] * self.u[k],
                j[k][1] - self.beta * ju[1] * self.u[k],
            ];
        }
    }
}

/// `v ← (v + B δ)/‖v + B δ‖`: the sphere retraction.
pub fn sphere_plus<const N: usize>(v: &[f64; N], delta: &[f64]) -> [f64; N] {
    let bd = Householder::new(v).apply(delta);
    let mut out = [0.0; N];
    for k in 0..N {
        out[k] = v[k] + bd[k];
    }
    let n = out.iter().map(|a| a * a).sum::<f64>().sqrt();
    out.map(|a| a / n)
}

/// `exp([w]×)` by Rodrigues' formula (second-order series near zero).
pub fn angle_axis_to_matrix(w: &[f64; 3]) -> Matrix3<f64> {
    let th2 = w[0] * w[0] + w[1] * w[1] + w[2] * w[2];
    let k = Matrix3::new(0.0, -w[2], w[1], w[2], 0.0, -w[0], -w[1], w[0], 0.0);
    if th2 < 1e-20 {
        return Matrix3::identity() + k + 0.5 * k * k;
    }
    let th = th2.sqrt();
    Matrix3::identity() + (th.sin() / th) * k + ((1.0 - th.cos()) / th2) * (k * k)
}

/// Metric pose update: `R ← exp([δ_r]×) R`, `t ← t + δ_t`.
pub fn pose_plus(cam: &PoseBlock, delta: &[f64]) -> PoseBlock {
    let r = angle_axis_to_matrix(&[delta[0], delta[1], delta[2]]) * rot(cam);
    let mut out = [0.0; 12];
    for i in 0..3 {
        for j in 0..3 {
            out[3 * i + j] = r[(i, j)];
        }
        out[9 + i] = cam[9 + i] + delta[3 + i];
    }
    out
}

#[cfg(test)]
#[path = "residual_tests.rs"]
mod tests;
