//! Analytic Jacobians against forward-mode automatic differentiation (num-dual) and against central
//! finite differences through the manifold updates.

use super::*;
use num_dual::Dual64;

type D = Dual64;

fn c(v: f64) -> D {
    D::from_re(v)
}

fn pose() -> PoseBlock {
    let r = angle_axis_to_matrix(&[0.2, -0.3, 0.1]);
    let mut b = [0.0; 12];
    for i in 0..3 {
        for j in 0..3 {
            b[3 * i + j] = r[(i, j)];
        }
    }
    b[9..].copy_from_slice(&[0.3, -0.2, 4.0]);
    b
}

const INTR: [f64; 9] = [520.0, 1.05, 0.7, 320.0, 241.0, -0.12, 0.03, 0.0, 0.0];
const X: [f64; 4] = [0.4, -0.3, 1.2, 1.0];
const OBS: [f64; 2] = [300.0, 200.0];

/// The metric model in dual numbers, parameterised like the analytic one: 16 parameters
/// (δrot, t, intrinsics, point); the rotation uses exp ≈ I + [δ]×, exact to first order at δ = 0.
fn metric_dual(params: &[D; 16], base: &PoseBlock) -> [D; 2] {
    let r = |i: usize, j: usize| c(base[3 * i + j]);
    let x = [params[13], params[14], params[15]];
    let rx: Vec<D> = (0..3)
        .map(|i| r(i, 0) * x[0] + r(i, 1) * x[1] + r(i, 2) * x[2])
        .collect();
    let w = [params[0], params[1], params[2]];
    let cross = [
        w[1] * rx[2] - w[2] * rx[1],
        w[2] * rx[0] - w[0] * rx[2],
        w[0] * rx[1] - w[1] * rx[0],
    ];
    let xc: Vec<D> = (0..3).map(|i| rx[i] + cross[i] + params[3 + i]).collect();
    let (nx, ny) = (xc[0] / xc[2], xc[1] / xc[2]);
    let k = &params[6..13];
    let r2 = nx * nx + ny * ny;
    let d = c(1.0) + k[5] * r2 + k[6] * r2 * r2;
    let (xd, yd) = (nx * d, ny * d);
    [
        k[0] * xd + k[2] * yd + k[3] - OBS[0],
        k[1] * k[0] * yd + k[4] - OBS[1],
    ]
}

#[test]
fn metric_jacobian_matches_num_dual() {
    let cam = pose();
    let (mut jpose, mut jintr, mut jpt) = ([[0.0; 2]; 6], [[0.0; 2]; 9], [[0.0; 2]; 3]);
    let still = Motion::default();
    let r = metric_jacobian(
        &cam, &INTR, &X, OBS, &still, &mut jpose, &mut jintr, &mut jpt,
    );
    let r0 = metric_residual(&cam, &INTR, &X, OBS, &still);
    assert!((r[0] - r0[0]).abs() < 1e-12 && (r[1] - r0[1]).abs() < 1e-12);
    let mut analytic = Vec::new();
    analytic.extend_from_slice(&jpose);
    analytic.extend_from_slice(&jintr[..7]);
    analytic.extend_from_slice(&jpt);
    let base: [f64; 16] = [
        0.0, 0.0, 0.0, cam[9], cam[10], cam[11], INTR[0], INTR[1], INTR[2], INTR[3], INTR[4],
        INTR[5], INTR[6], X[0], X[1], X[2],
    ];
    for (k, column) in analytic.iter().enumerate() {
        let params: [D; 16] =
            std::array::from_fn(|i| D::new(base[i], if i == k { 1.0 } else { 0.0 }));
        let out = metric_dual(&params, &cam);
        assert!((out[0].re - r[0]).abs() < 1e-9 && (out[1].re - r[1]).abs() < 1e-9);
        for a in 0..2 {
            let (want, got) = (out[a].eps, column[a]);
            assert!(
                (want - got).abs() <= 1e-9 * (1.0 + want.abs()),
                "param {k} row {a}: dual {want} analytic {got}"
            );
        }
    }
}

fn assert_close(fd: [f64; 2], an: [f64; 2], what: &str) {
    for a in 0..2 {
        assert!(
            (fd[a] - an[a]).abs() <= 1e-5 * (1.0 + an[a].abs()),
            "{what} row {a}: fd {} analytic {}",
            fd[a],
            an[a]
        );
    }
}

#[test]
fn metric_jacobian_matches_finite_differences_through_pose_plus() {
    let cam = pose();
    // A still camera, then a rolling shutter's: the frame turning and moving during its read-out.
    let rolling = Motion {
        velocity: [0.02, -0.05, 0.01, 0.03, 0.01, -0.02],
        basis: [0.31, -0.42],
    };
    let mut intr = INTR;
    (intr[7], intr[8]) = (0.2, 0.7);
    for (motion, intr) in [(Motion::default(), INTR), (rolling, intr)] {
        let (mut jpose, mut jintr, mut jpt) = ([[0.0; 2]; 6], [[0.0; 2]; 9], [[0.0; 2]; 3]);
        metric_jacobian(
            &cam, &intr, &X, OBS, &motion, &mut jpose, &mut jintr, &mut jpt,
        );
        // Central differences of the residual along one parameter, moved by ±h.
        let h = 1e-6;
        let central = |r: &dyn Fn(f64) -> [f64; 2]| {
            let (rp, rm) = (r(h), r(-h));
            [(rp[0] - rm[0]) / (2.0 * h), (rp[1] - rm[1]) / (2.0 * h)]
        };
        for k in 0..6 {
            let fd = central(&|e| {
                let mut d = [0.0; 6];
                d[k] = e;
                metric_residual(&pose_plus(&cam, &d), &intr, &X, OBS, &motion)
            });
            assert_close(fd, jpose[k], &format!("pose {k}"));
        }
        for k in 0..9 {
            let fd = central(&|e| {
                let mut i = intr;
                i[k] += e;
                metric_residual(&cam, &i, &X, OBS, &motion)
            });
            assert_close(fd, jintr[k], &format!("intrinsic {k}"));
        }
        for k in 0..3 {
            let fd = central(&|e| {
                let mut x = X;
                x[k] += e;
                metric_residual(&cam, &intr, &x, OBS, &motion)
            });
            assert_close(fd, jpt[k], &format!("point {k}"));
        }
    }
}

#[test]
fn projective_jacobian_matches_finite_differences_on_the_spheres() {
    let mut p = [
        500.0, 2.0, 320.0, 10.0, -1.0, 505.0, 240.0, -30.0, 0.01, -0.02, 1.0, 4.0,
    ];
    let n = p.iter().map(|v| v * v).sum::<f64>().sqrt();
    p.iter_mut().for_each(|v| *v /= n);
    let xn = X.iter().map(|v| v * v).sum::<f64>().sqrt();
    let x = X.map(|v| -v / xn); // a negative representative must work too
    let (mut jcam, mut jpt) = ([[0.0; 2]; 11], [[0.0; 2]; 3]);
    let r = projective_jacobian(&p, &x, OBS, &mut jcam, &mut jpt);
    let r0 = projective_residual(&p, &x, OBS);
    assert!((r[0] - r0[0]).abs() < 1e-9 && (r[1] - r0[1]).abs() < 1e-9);
    let h = 1e-7;
    for k in 0..11 {
        let mut d = [0.0; 11];
        d[k] = h;
        let rp = projective_residual(&sphere_plus(&p, &d), &x, OBS);
        d[k] = -h;
        let rm = projective_residual(&sphere_plus(&p, &d), &x, OBS);
        assert_close(
            [(rp[0] - rm[0]) / (2.0 * h), (rp[1] - rm[1]) / (2.0 * h)],
            jcam[k],
            &format!("P {k}"),
        );
    }
    for k in 0..3 {
        let mut d = [0.0; 3];
        d[k] = h;
        let rp = projective_residual(&p, &sphere_plus(&x, &d), OBS);
        d[k] = -h;
        let rm = projective_residual(&p, &sphere_plus(&x, &d), OBS);
        assert_close(
            [(rp[0] - rm[0]) / (2.0 * h), (rp[1] - rm[1]) / (2.0 * h)],
            jpt[k],
            &format!("X {k}"),
        );
    }
}

#[test]
fn householder_basis_is_orthonormal_and_tangent() {
    let v = [0.3, -0.5, 0.1, -0.8];
    let h = Householder::new(&v);
    let cols: Vec<[f64; 4]> = (0..3)
        .map(|k| h.apply(&[0, 1, 2].map(|i| if i == k { 1.0 } else { 0.0 })))
        .collect();
    for a in 0..3 {
        assert!(
            cols[a]
                .iter()
                .zip(&v)
                .map(|(x, y)| x * y)
                .sum::<f64>()
                .abs()
                < 1e-12
        );
        for b in 0..3 {
            let dot: f64 = cols[a].iter().zip(&cols[b]).map(|(x, y)| x * y).sum();
            assert!((dot - if a == b { 1.0 } else { 0.0 }).abs() < 1e-12);
        }
    }
    let r = angle_axis_to_matrix(&[0.3, 0.2, -0.1]);
    assert!((r * r.transpose() - Matrix3::identity()).norm() < 1e-12);
}
