//! `handheld bench bundle`: bundle adjustment on a BAL problem (compare with Ceres' `bundle_adjuster`:
//! cost `½Σ‖r‖²`, no gauge fixing, every camera refining its own `f, k1, k2`) or on a large synthetic
//! problem (`--synthetic 1000x200000`) that exercises the sparse Schur solver.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use clap::{Args, ValueEnum};
use handheld_bundle::{
    bundle_adjust_metric, BundleOptions, BundleSummary, CameraModel, GaussianPrior, IntrinsicsMask, LinearSolverKind,
    MetricBundleConfig, Problem, RobustLoss,
};

use crate::args::GlobalArgs;
use crate::ui::{print_result, Bars};

#[derive(Debug, Clone, Copy, ValueEnum, PartialEq, Eq)]
pub enum RobustArg {
    None,
    Huber,
    Cauchy,
}

#[derive(Debug, Clone, Copy, ValueEnum, PartialEq, Eq)]
pub enum SolverArg {
    Auto,
    Dense,
    Sparse,
}

#[derive(Debug, Args)]
pub struct BenchBundleArgs {
    /// A BAL problem file (`problem-49-7776-pre.txt`).
    #[arg(long, required_unless_present = "synthetic", conflicts_with = "synthetic")]
    pub bal: Option<PathBuf>,
    /// A synthetic problem `CAMERASxPOINTS` instead, e.g. `1000x200000`.
    #[arg(long)]
    pub synthetic: Option<String>,
    /// Maximum Levenberg–Marquardt iterations.
    #[arg(long, default_value_t = 50)]
    pub iterations: usize,
    /// Robust loss.
    #[arg(long, value_enum, default_value_t = RobustArg::None)]
    pub robust: RobustArg,
    /// Scale of the robust loss in pixels.
    #[arg(long, default_value_t = 1.0)]
    pub robust_scale: f64,
    /// Worker threads (0: all cores).
    #[arg(long, default_value_t = 0)]
    pub threads: usize,
    /// Linear solver for the reduced camera system.
    #[arg(long, value_enum, default_value_t = SolverArg::Auto)]
    pub linear_solver: SolverArg,
    /// Seed of the synthetic problem.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
}

pub fn run(a: &BenchBundleArgs, g: &GlobalArgs, bars: &Bars) -> anyhow::Result<()> {
    let options = BundleOptions {
        max_iterations: a.iterations,
        loss: match a.robust {
            RobustArg::None => RobustLoss::None,
            RobustArg::Huber => RobustLoss::Huber(a.robust_scale),
            RobustArg::Cauchy => RobustLoss::Cauchy(a.robust_scale),
        },
        linear_solver: match a.linear_solver {
            SolverArg::Auto => LinearSolverKind::Auto,
            SolverArg::Dense => LinearSolverKind::DenseSchur,
            SolverArg::Sparse => LinearSolverKind::SparseSchur,
        },
        num_threads: a.threads,
        ..Default::default()
    };
    let t_load = Instant::now();
    let (name, summary, counts) = if let Some(path) = &a.bal {
        let bal = handheld_io::bal::read_bal(path)?;
        let mut rec = bal.to_metric_reconstruction();
        let counts = (bal.cameras.len(), bal.points.len(), bal.observations.len());
        let config = MetricBundleConfig { refine: IntrinsicsMask::focal_and_radial(), fix_first_view: false, ..Default::default() };
        let load = t_load.elapsed().as_secs_f64();
        tracing::info!(load_seconds = load, "loaded {}", path.display());
        let s = bundle_adjust_metric(&mut rec, &config, &options).with_context(|| format!("bundle adjustment of {}", path.display()))?;
        (path.display().to_string(), s, counts)
    } else {
        let spec = a.synthetic.as_deref().unwrap_or_default();
        let (nc, np) = parse_size(spec)?;
        let mut problem = synthetic_problem(nc, np, a.seed);
        let counts = (nc, problem.points.len(), problem.num_observations());
        let s = handheld_bundle::solve_with_progress(&mut problem, &options, bars)?;
        (format!("synthetic {spec}"), s, counts)
    };
    report(g, &name, &summary, counts, &options);
    Ok(())
}

fn report(g: &GlobalArgs, name: &str, s: &BundleSummary, (nc, np, no): (usize, usize, usize), o: &BundleOptions) {
    let per_iter = s.total_seconds / s.iterations.max(1) as f64;
    let threads = if o.num_threads == 0 { rayon::current_num_threads() } else { o.num_threads };
    let value = serde_json::json!({
        "problem": name,
        "cameras": nc,
        "points": np,
        "observations": no,
        "initial_cost": s.initial_cost,
        "final_cost": s.final_cost,
        "initial_rms_px": s.initial_rms_px,
        "final_rms_px": s.final_rms_px,
        "iterations": s.iterations,
        "successful_steps": s.successful_steps,
        "termination": s.termination.name(),
        "total_seconds": s.total_seconds,
        "seconds_per_iteration": per_iter,
        "linear_solver_seconds": s.linear_solver_seconds,
        "linear_solver": s.linear_solver.name(),
        "reduced_parameters": s.num_camera_parameters,
        "threads": threads,
    });
    let human = format!(
        "{name}: {nc} cameras, {np} points, {no} observations\ncost {:.6e} -> {:.6e} (rms {:.3} -> {:.3} px) in {} iterations ({}), \
         {:.3} s ({:.4} s/iteration, {} solver)",
        s.initial_cost,
        s.final_cost,
        s.initial_rms_px,
        s.final_rms_px,
        s.iterations,
        s.termination.name(),
        s.total_seconds,
        per_iter,
        s.linear_solver.name()
    );
    print_result(g, &value, &human);
}

fn parse_size(spec: &str) -> anyhow::Result<(usize, usize)> {
    let bad = || anyhow::anyhow!("--synthetic expects CAMERASxPOINTS (e.g. 1000x200000), got `{spec}`");
    let (c, p) = spec.split_once(['x', 'X']).ok_or_else(bad)?;
    let (c, p): (usize, usize) = (c.trim().parse().map_err(|_| bad())?, p.trim().parse().map_err(|_| bad())?);
    if c < 2 || p < 1 {
        return Err(bad());
    }
    Ok((c, p))
}

/// SplitMix64: a tiny seeded generator (the CLI does not depend on `rand`).
struct Rng(u64);

impl Rng {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * ((self.next_u64() >> 11) as f64 / (1u64 << 53) as f64)
    }
    fn gauss(&mut self) -> f64 {
        let (u, v) = (self.uniform(1e-12, 1.0), self.uniform(0.0, 1.0));
        (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
    }
}

/// A BAL-like synthetic problem: `nc` cameras on a circle of radius 100 looking outwards (each with its
/// own `f, k1, k2`), `np` points 8–12 units in front of a random camera and seen by 3–8 consecutive
/// cameras, 0.5 px noise, and perturbed initial poses, points and focal lengths.
fn synthetic_problem(nc: usize, np: usize, seed: u64) -> Problem {
    let mut rng = Rng(seed);
    let mut p = Problem::new(CameraModel::Metric);
    let (f, k1, k2) = (500.0, -0.05, 0.01);
    let mut truth = Vec::with_capacity(nc);
    for i in 0..nc {
        let th = std::f64::consts::TAU * i as f64 / nc as f64;
        // Camera z axis radial outwards, y axis down (world −z), x = y × z.
        let z = nalgebra::Vector3::new(th.cos(), th.sin(), 0.0);
        let y = nalgebra::Vector3::new(0.0, 0.0, -1.0);
        let x = y.cross(&z);
        let r = nalgebra::Matrix3::from_rows(&[x.transpose(), y.transpose(), z.transpose()]);
        let c = z * 100.0;
        let t = -(r * c);
        truth.push((r, t));
        let dr = handheld_bundle::residual::angle_axis_to_matrix(&[0.0, 1.0, 2.0].map(|_| rng.gauss() * 0.002));
        let rp = dr * r;
        let mut b = [0.0; 12];
        for a in 0..3 {
            for bcol in 0..3 {
                b[3 * a + bcol] = rp[(a, bcol)];
            }
            b[9 + a] = t[a] + rng.gauss() * 0.05;
        }
        p.cameras.push(b);
        p.camera_constant.push(false);
        p.camera_group.push(i);
        p.groups.push([f * (1.0 + 0.01 * rng.gauss()), 1.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
        p.group_free.push(IntrinsicsMask::focal_and_radial().to_array());
        p.group_priors.push([None::<GaussianPrior>; 7]);
    }
    for _ in 0..np {
        let c0 = (rng.next_u64() % nc as u64) as usize;
        let (r, t) = &truth[c0];
        let depth = rng.uniform(8.0, 12.0);
        let pc = nalgebra::Vector3::new(rng.uniform(-0.4, 0.4) * depth, rng.uniform(-0.3, 0.3) * depth, depth);
        let xw = r.transpose() * (pc - t);
        let len = 3 + (rng.next_u64() % 6) as usize;
        let idx = p.points.len() as u32;
        let mut seen = 0;
        for k in 0..len {
            let c = (c0 + nc + k - len / 2) % nc;
            let (r, t) = &truth[c];
            let xc = r * xw + t;
            if xc.z < 1.0 {
                continue;
            }
            let (nx, ny) = (xc.x / xc.z, xc.y / xc.z);
            let r2 = nx * nx + ny * ny;
            let d = 1.0 + k1 * r2 + k2 * r2 * r2;
            let (u, v) = (f * d * nx, f * d * ny);
            if u.abs() > 320.0 || v.abs() > 240.0 {
                continue;
            }
            p.obs_camera.push(c as u32);
            p.obs_point.push(idx);
            p.obs_xy.push([u + 0.5 * rng.gauss(), v + 0.5 * rng.gauss()]);
            seen += 1;
        }
        if seen < 2 {
            let n = p.obs_xy.len() - seen;
            p.obs_camera.truncate(n);
            p.obs_point.truncate(n);
            p.obs_xy.truncate(n);
            continue;
        }
        p.points.push([xw.x + 0.05 * rng.gauss(), xw.y + 0.05 * rng.gauss(), xw.z + 0.05 * rng.gauss(), 1.0]);
    }
    p
}
