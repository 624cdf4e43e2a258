//! `handheld bench mesh`: dense depth and the fused mesh of a large outdoor scene against exact
//! ground truth (issue #35). testkit's street ([`Scene::street_scene`]: 160 m of façades with
//! relief, parked cars, a building closing it at 150 m; depths from 1.5 to 150 m) is rendered along
//! a drive down the street and a hand-held walk across it. With the exact cameras, the dense stage
//! (§4) and the fusion (§5.1, voxel size following the depth) run with their defaults, and:
//! - **depth**: per view, the fill (pixels with a surface that got a depth), the same over the
//!   pixels whose surface another view also sees (no stereo can give the rest a depth: the ground
//!   leaving the bottom of a drive's first frame), and the median relative error against the
//!   rendered depth;
//! - **mesh accuracy**: the 90th percentile over the mesh's vertices of the distance to the true
//!   surface divided by the vertex's distance from the nearest camera;
//! - **mesh completeness**: of the true surface that at least two views see (every 4th pixel of
//!   each view's exact depth, kept where another view's exact depth agrees within 1 %), the fraction
//!   within 1 % of its distance from the nearest camera of the mesh;
//! - time per stage and peak resident memory (`VmHWM`, reset before each path).

use std::time::Instant;

use handheld_core::{FloatMap, ImageId, NoProgress, PosedView};
use handheld_dense::{dense_reconstruct, DenseOptions, SparsePoints};
use handheld_mesh::{fuse_depth_maps, FusionOptions, FusionSummary, MeshIndex};
use handheld_testkit::path::PathOptions;
use handheld_testkit::render::{render_sequence_with_scene, SequenceOptions, SyntheticSequence};
use handheld_testkit::Scene;
use nalgebra::{Point3, Vector3};
use serde::{Deserialize, Serialize};

use super::scale::{peak_rss_mb, reset_peak_rss};
use crate::error::{EvalError, Result};

/// Options of [`bench_mesh`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct MeshBenchOptions {
    /// Image width (height is 3/4 of it). Default 640.
    pub width: u32,
    /// Frames per path. Default 20.
    pub frames: usize,
    /// Metres the car drives. Default 12.
    pub drive_m: f64,
    /// Metres the walk crosses. Default 4.
    pub walk_m: f64,
    pub seed: u64,
    /// Where to write each path's first and last frame and the fused mesh (`<path>-first.png`,
    /// `<path>-last.png`, `<path>.ply`), to look at. Default none.
    pub out: Option<std::path::PathBuf>,
    /// The fusion's options (its defaults unless changed, e.g. `tsdf.max_depth_std`).
    pub fusion: FusionOptions,
}

impl Default for MeshBenchOptions {
    fn default() -> Self {
        Self {
            width: 640,
            frames: 20,
            drive_m: 12.0,
            walk_m: 4.0,
            seed: 0,
            out: None,
            fusion: FusionOptions::default(),
        }
    }
}

/// Depth figures of one path.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct DepthFigures {
    /// Over all views' pixels with a surface: the fraction that got a depth.
    pub fill: f64,
    /// The lowest per-view fill.
    pub fill_min: f64,
    /// Each view's fill, in frame order.
    #[serde(default)]
    pub fill_per_view: Vec<f64>,
    /// Each view's fill over the pixels whose surface another view also sees (every 4th pixel,
    /// kept where another view's exact depth agrees within 1 %): a pixel no other view sees cannot
    /// get a depth from stereo (the bottom rows of a drive's first frame).
    #[serde(default)]
    pub fill_seen_twice_per_view: Vec<f64>,
    /// The lowest of those.
    #[serde(default)]
    pub fill_seen_twice_min: f64,
    /// Median of |depth − truth| / truth over the filled pixels.
    pub relative_error_median: f64,
    /// The same at the 90th percentile.
    pub relative_error_p90: f64,
    /// Truth's depth range over the views (1st and 99th percentiles, m).
    pub true_depth_range_m: [f64; 2],
    /// Fill and median relative error per band of true depth.
    pub by_depth: Vec<Band>,
}

/// Figures of one band of true depth (or camera distance) `[from_m, to_m)`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Band {
    pub from_m: f64,
    pub to_m: f64,
    /// The share of the pixels (or surface samples) in the band.
    pub share: f64,
    /// Depth: the fill; mesh: the completeness within 1 %.
    pub fraction: f64,
    /// Depth: the median relative error over the filled pixels.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub relative_error_median: Option<f64>,
}

/// Bands of true depth (m).
const BANDS: [f64; 6] = [0.0, 5.0, 10.0, 20.0, 40.0, f64::INFINITY];

fn band_of(z: f64) -> usize {
    BANDS
        .windows(2)
        .position(|w| z >= w[0] && z < w[1])
        .unwrap_or(BANDS.len() - 2)
}

/// Mesh figures of one path.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MeshFigures {
    /// 90th percentile of (distance to the true surface) / (distance from the nearest camera).
    pub relative_accuracy_90: f64,
    /// Fraction of the surface two views see within 1 % of its camera distance of the mesh.
    pub completeness: f64,
    /// The same within 2 %.
    pub completeness_2pct: f64,
    /// Completeness (1 %) per band of distance from the nearest camera.
    pub by_distance: Vec<Band>,
    pub faces: usize,
    pub fusion: FusionSummary,
}

/// One path.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StreetRun {
    /// `drive` or `walk`.
    pub path: String,
    pub frames: usize,
    pub width: u32,
    pub height: u32,
    pub depth: DepthFigures,
    pub mesh: Option<MeshFigures>,
    /// The fusion's error, when it failed.
    pub mesh_error: Option<String>,
    pub render_seconds: f64,
    pub dense_seconds: f64,
    pub dense_seconds_per_megapixel: f64,
    pub mesh_seconds: f64,
    pub peak_rss_mb: Option<f64>,
}

/// The report.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MeshBenchReport {
    pub options: MeshBenchOptions,
    pub runs: Vec<StreetRun>,
}

/// Runs the street bench (see the module documentation).
pub fn bench_mesh(o: &MeshBenchOptions) -> Result<MeshBenchReport> {
    if o.frames < 3 {
        return Err(EvalError::option("--frames", "must be at least 3"));
    }
    let mut runs = Vec::new();
    for (name, path) in [
        ("drive", PathOptions::street_drive(o.frames, o.drive_m)),
        ("walk", PathOptions::street_walk(o.frames, o.walk_m)),
    ] {
        reset_peak_rss();
        let seq_opts = SequenceOptions {
            seed: o.seed,
            width: o.width,
            height: o.width * 3 / 4,
            num_frames: o.frames,
            path,
            focal_px: Some(0.9 * o.width as f64),
            k1: 0.0,
            k2: 0.0,
            samples_per_axis: 2,
            ..Default::default()
        };
        let t = Instant::now();
        let seq = render_sequence_with_scene(Scene::street_scene(o.seed), &seq_opts)
            .map_err(|e| EvalError::option("--width", e))?;
        let render_seconds = t.elapsed().as_secs_f64();
        runs.push(run_path(name, &seq, render_seconds, o)?);
    }
    Ok(MeshBenchReport {
        options: o.clone(),
        runs,
    })
}

fn run_path(
    name: &str,
    seq: &SyntheticSequence,
    render_seconds: f64,
    o: &MeshBenchOptions,
) -> Result<StreetRun> {
    let (ids, views): (Vec<ImageId>, Vec<PosedView>) = (0..seq.images.len())
        .filter_map(|i| {
            let view =
                PosedView::from_posed(format!("{i:03}"), seq.frame(i)?, seq.images[i].clone());
            Some((ImageId(i as u32), view))
        })
        .unzip();
    // The exact points with the views that see them, as a model's tracks give them.
    let points = SparsePoints::from_tracks(seq.gt.points.values(), &ids);
    let t = Instant::now();
    let mut dense: Vec<PosedView> = Vec::new();
    dense_reconstruct(
        &views,
        &points,
        &DenseOptions::default(),
        &NoProgress,
        |r| {
            dense.push(r.view);
            Ok(())
        },
    )
    .map_err(|e| EvalError::option("dense", e.to_string()))?;
    let dense_seconds = t.elapsed().as_secs_f64();
    dense.sort_by(|a, b| a.name.cmp(&b.name));
    let depth = depth_figures(&dense, &seq.depths);
    let t = Instant::now();
    let fused = fuse_depth_maps(&dense, &o.fusion, &NoProgress);
    let mesh_seconds = t.elapsed().as_secs_f64();
    let centres: Vec<Vector3<f64>> = views.iter().map(|v| v.posed.center().coords).collect();
    if let Some(dir) = &o.out {
        std::fs::create_dir_all(dir).map_err(|e| EvalError::option("--out", e.to_string()))?;
        for (tag, img) in [("first", seq.images.first()), ("last", seq.images.last())] {
            if let Some(img) = img {
                img.save(dir.join(format!("{name}-{tag}.png")))
                    .map_err(|e| EvalError::option("--out", e.to_string()))?;
            }
        }
        let mid = dense.len() / 2;
        if let (Some(v), Some(gt)) = (dense.get(mid), seq.depths.get(mid)) {
            if let Some(d) = &v.depth {
                depth_pair_png(gt, d)
                    .save(dir.join(format!("{name}-depth.png")))
                    .map_err(|e| EvalError::option("--out", e.to_string()))?;
            }
        }
        if let Ok((m, _)) = &fused {
            handheld_io::ply::write_mesh(
                &dir.join(format!("{name}.ply")),
                m,
                handheld_io::ply::PlyFormat::BinaryLittleEndian,
            )
            .map_err(|e| EvalError::option("--out", e.to_string()))?;
        }
    }
    let (mesh, mesh_error) = match fused {
        Ok((mesh, fusion)) => {
            let truth: Vec<PosedView> = views
                .iter()
                .enumerate()
                .map(|(i, v)| PosedView {
                    depth: Some(seq.depths[i].clone()),
                    image: image::RgbImage::new(0, 0),
                    ..v.clone()
                })
                .collect();
            (
                Some(mesh_figures(&mesh, fusion, seq, &truth, &centres)),
                None,
            )
        }
        Err(e) => (None, Some(e.to_string())),
    };
    let mp = (o.width as f64 * (o.width * 3 / 4) as f64) / 1e6;
    Ok(StreetRun {
        path: name.into(),
        frames: views.len(),
        width: o.width,
        height: o.width * 3 / 4,
        depth,
        mesh,
        mesh_error,
        render_seconds,
        dense_seconds,
        dense_seconds_per_megapixel: dense_seconds / (views.len() as f64 * mp),
        mesh_seconds,
        peak_rss_mb: peak_rss_mb(),
    })
}

fn percentile(v: &mut [f64], q: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * q).round() as usize]
}

fn depth_figures(dense: &[PosedView], truth: &[FloatMap]) -> DepthFigures {
    let (mut surface, mut filled) = (0usize, 0usize);
    let mut fill_min = f64::INFINITY;
    let mut fill_per_view = Vec::with_capacity(dense.len());
    let mut fill_seen_twice_per_view = Vec::with_capacity(dense.len());
    let mut rel = Vec::new();
    let mut depths = Vec::new();
    let nb = BANDS.len() - 1;
    let (mut b_all, mut b_fill) = (vec![0usize; nb], vec![0usize; nb]);
    let mut b_rel: Vec<Vec<f64>> = vec![Vec::new(); nb];
    for (v, gt) in dense.iter().zip(truth) {
        let Some(d) = &v.depth else { continue };
        let (mut s, mut f) = (0usize, 0usize);
        for (i, &g) in gt.data.iter().enumerate() {
            if !(g.is_finite() && g > 0.0) {
                continue;
            }
            s += 1;
            if i % 16 == 0 {
                depths.push(g as f64);
            }
            let b = band_of(g as f64);
            b_all[b] += 1;
            let z = d.data[i];
            if z.is_finite() && z > 0.0 {
                f += 1;
                b_fill[b] += 1;
                let e = ((z - g) / g).abs() as f64;
                rel.push(e);
                if i % 4 == 0 {
                    b_rel[b].push(e);
                }
            }
        }
        surface += s;
        filled += f;
        fill_min = fill_min.min(f as f64 / s.max(1) as f64);
        fill_per_view.push(f as f64 / s.max(1) as f64);
        fill_seen_twice_per_view.push(fill_seen_twice(v, gt, dense, truth));
    }
    DepthFigures {
        fill: filled as f64 / surface.max(1) as f64,
        fill_min,
        fill_per_view,
        fill_seen_twice_min: fill_seen_twice_per_view
            .iter()
            .copied()
            .fold(f64::INFINITY, f64::min),
        fill_seen_twice_per_view,
        relative_error_median: percentile(&mut rel, 0.5),
        relative_error_p90: percentile(&mut rel, 0.9),
        true_depth_range_m: [percentile(&mut depths, 0.01), percentile(&mut depths, 0.99)],
        by_depth: (0..nb)
            .map(|b| Band {
                from_m: BANDS[b],
                to_m: BANDS[b + 1],
                share: b_all[b] as f64 / surface.max(1) as f64,
                fraction: b_fill[b] as f64 / b_all[b].max(1) as f64,
                relative_error_median: Some(percentile(&mut b_rel[b], 0.5)),
            })
            .collect(),
    }
}

/// `view`'s fill over every 4th pixel whose true surface another view's exact depth confirms
/// (within 1 %). `views` and `truth` are in the same order.
fn fill_seen_twice(
    view: &PosedView,
    gt: &FloatMap,
    views: &[PosedView],
    truth: &[FloatMap],
) -> f64 {
    let Some(d) = &view.depth else { return 0.0 };
    let cam = &view.posed;
    let world_from_cam = cam.cam_from_world.inverse();
    let (mut seen, mut filled) = (0usize, 0usize);
    for (i, &g) in gt.data.iter().enumerate().step_by(4) {
        if !(g.is_finite() && g > 0.0) {
            continue;
        }
        let px = nalgebra::Vector2::new((i % gt.width) as f64, (i / gt.width) as f64);
        let ray = cam.camera.ray_in_cam(px);
        let p = world_from_cam * Point3::from(ray * (g as f64 / ray.z));
        let other_sees = views.iter().zip(truth).any(|(w, wt)| {
            if std::ptr::eq(w, view) {
                return false;
            }
            let pc = w.posed.to_cam(&p);
            let Some(q) = w.posed.project(&p) else {
                return false;
            };
            let (x, y) = (q.x.round(), q.y.round());
            if x < 0.0 || y < 0.0 || x >= wt.width as f64 || y >= wt.height as f64 {
                return false;
            }
            let z = wt.data[y as usize * wt.width + x as usize] as f64;
            z > 0.0 && (z - pc.z).abs() < 0.01 * pc.z
        });
        if other_sees {
            seen += 1;
            let z = d.data[i];
            if z.is_finite() && z > 0.0 {
                filled += 1;
            }
        }
    }
    filled as f64 / seen.max(1) as f64
}

fn nearest_camera(p: &Point3<f64>, centres: &[Vector3<f64>]) -> f64 {
    centres
        .iter()
        .map(|c| (p.coords - c).norm())
        .fold(f64::INFINITY, f64::min)
}

fn mesh_figures(
    mesh: &handheld_core::TriMesh,
    fusion: FusionSummary,
    seq: &SyntheticSequence,
    truth: &[PosedView],
    centres: &[Vector3<f64>],
) -> MeshFigures {
    let gt = MeshIndex::new(&seq.mesh);
    let mut acc: Vec<f64> = mesh
        .vertices
        .positions
        .iter()
        .map(|p| {
            let q = Point3::new(p[0] as f64, p[1] as f64, p[2] as f64);
            gt.distance(&q) / nearest_camera(&q, centres)
        })
        .collect();
    // The true surface two views see: samples of each view's exact depth that another view's
    // exact depth confirms.
    let samples = handheld_mesh::eval::visible_surface_samples(truth, 4).unwrap_or_default();
    let seen_twice: Vec<Point3<f64>> = samples
        .into_iter()
        .filter(|p| {
            truth
                .iter()
                .filter(|v| {
                    let pc = v.posed.cam_from_world * p;
                    let Some(px) = v.posed.camera.project(&v.posed.cam_from_world, p) else {
                        return false;
                    };
                    let (x, y) = (px.x.round(), px.y.round());
                    let d = v.depth.as_ref().expect("truth has depth");
                    if x < 0.0 || y < 0.0 || x >= d.width as f64 || y >= d.height as f64 {
                        return false;
                    }
                    let z = d.data[y as usize * d.width + x as usize] as f64;
                    z > 0.0 && (z - pc.z).abs() < 0.01 * pc.z
                })
                .count()
                >= 2
        })
        .collect();
    let ours = MeshIndex::new(mesh);
    let (mut within1, mut within2) = (0usize, 0usize);
    let nb = BANDS.len() - 1;
    let (mut b_all, mut b_in) = (vec![0usize; nb], vec![0usize; nb]);
    for p in &seen_twice {
        let r = nearest_camera(p, centres);
        let d = ours.distance_within(p, 0.02 * r);
        let b = band_of(r);
        b_all[b] += 1;
        if d <= 0.01 * r {
            within1 += 1;
            b_in[b] += 1;
        }
        if d <= 0.02 * r {
            within2 += 1;
        }
    }
    let n = seen_twice.len().max(1) as f64;
    MeshFigures {
        relative_accuracy_90: percentile(&mut acc, 0.9),
        completeness: within1 as f64 / n,
        completeness_2pct: within2 as f64 / n,
        by_distance: (0..nb)
            .map(|b| Band {
                from_m: BANDS[b],
                to_m: BANDS[b + 1],
                share: b_all[b] as f64 / n,
                fraction: b_in[b] as f64 / b_all[b].max(1) as f64,
                relative_error_median: None,
            })
            .collect(),
        faces: mesh.faces.len(),
        fusion,
    }
}

/// The true depth and the dense depth side by side, grey by log depth on one scale (1 m white,
/// 200 m black), red where there is none.
fn depth_pair_png(truth: &FloatMap, ours: &FloatMap) -> image::RgbImage {
    let (w, h) = (truth.width, truth.height);
    let grey = |z: f32| -> image::Rgb<u8> {
        if !(z.is_finite() && z > 0.0) {
            return image::Rgb([160, 0, 0]);
        }
        let t = ((z as f64).ln() / 200f64.ln()).clamp(0.0, 1.0);
        let g = (255.0 * (1.0 - t)) as u8;
        image::Rgb([g, g, g])
    };
    image::RgbImage::from_fn(2 * w as u32, h as u32, |x, y| {
        let (x, y) = (x as usize, y as usize);
        if x < w {
            grey(truth.data[y * w + x])
        } else {
            grey(ours.data[y * w + x - w])
        }
    })
}

impl MeshBenchReport {
    /// The report in a few lines, for people (the CLI prints it without `--json`).
    pub fn summary_text(&self) -> String {
        let mut s = String::from(
            "path   depth fill  lowest view (seen twice)  rel err med  mesh acc90 (rel)  complete 1%  faces    left out  dense s  mesh s  peak MB\n",
        );
        for x in &self.runs {
            let m = x.mesh.as_ref();
            s += &format!(
                "{:<5}  {:>9.1}%  {:>12.1}% ({:>5.1}%)  {:>10.3}%  {:>15}  {:>11}  {:>7}  {:>8}  {:>7.1}  {:>6.1}  {:>7.0}\n",
                x.path,
                100.0 * x.depth.fill,
                100.0 * x.depth.fill_min,
                100.0 * x.depth.fill_seen_twice_min,
                100.0 * x.depth.relative_error_median,
                m.map_or("-".into(), |m| format!("{:.3}%", 100.0 * m.relative_accuracy_90)),
                m.map_or("-".into(), |m| format!("{:.1}%", 100.0 * m.completeness)),
                m.map_or(0, |m| m.faces),
                m.map_or("-".into(), |m| format!("{:.1}%", 100.0 * m.fusion.uncertain_fraction)),
                x.dense_seconds,
                x.mesh_seconds,
                x.peak_rss_mb.unwrap_or(f64::NAN),
            );
            if let Some(e) = &x.mesh_error {
                s += &format!("{}: mesh failed: {e}\n", x.path);
            }
        }
        s
    }
}
