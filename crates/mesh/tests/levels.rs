//! Fusion whose voxel size follows the depth (issue #35): a street-like scene seen from a camera
//! moving forward, with exact depth maps from 3 to 80 units (a ground plane, a façade along the
//! road, a far wall). One voxel size for that range is either too coarse near or too many voxels
//! far; the levels keep the error proportional to the distance with a fraction of the blocks.

use handheld_core::{
    Camera, CameraId, FloatMap, Intrinsics, NoProgress, PosedView, Rigid3, TriMesh,
};
use handheld_mesh::{fuse_depth_maps, FusionOptions, VoxelSize};
use image::RgbImage;
use nalgebra::Vector3;

const GROUND_Y: f64 = 1.6;
const FACADE_X: f64 = 6.0;
const FAR_Z: f64 = 80.0;
const W: usize = 320;
const H: usize = 240;
const F: f64 = 250.0;

fn centre(i: usize) -> Vector3<f64> {
    Vector3::new(0.0, 0.0, 0.8 * i as f64)
}

/// Six views driving along +z, looking down the road; exact z-depth of the nearest plane.
fn street_views(n: usize) -> Vec<PosedView> {
    let k = Intrinsics::pinhole(F, (W as f64 - 1.0) / 2.0, (H as f64 - 1.0) / 2.0);
    (0..n)
        .map(|i| {
            let c = centre(i);
            let cam = Camera {
                id: CameraId(0),
                width: W as u32,
                height: H as u32,
                intrinsics: k,
            };
            let pose = Rigid3::new(-c, Vector3::zeros());
            let mut depth = FloatMap::filled(W, H, 1, f32::NAN);
            for y in 0..H {
                for x in 0..W {
                    let (xn, yn) = ((x as f64 - k.pp.x) / F, (y as f64 - k.pp.y) / F);
                    let mut t = FAR_Z - c.z;
                    if yn > 0.0 {
                        t = t.min(GROUND_Y / yn);
                    }
                    if xn > 0.0 {
                        t = t.min(FACADE_X / xn);
                    }
                    depth.data[y * W + x] = t as f32;
                }
            }
            let mut v = PosedView::new(
                format!("v{i}"),
                cam,
                pose,
                RgbImage::new(W as u32, H as u32),
            );
            v.depth = Some(depth);
            v
        })
        .collect()
}

/// Distance of `p` from the nearest of the three planes.
fn surface_distance(p: &[f32; 3]) -> f64 {
    let [x, y, z] = p.map(|v| v as f64);
    (y - GROUND_Y)
        .abs()
        .min((x - FACADE_X).abs())
        .min((z - FAR_Z).abs())
}

/// The 90th percentile of the vertices' error relative to their distance from the nearest camera.
fn relative_error_90(mesh: &TriMesh, n: usize) -> f64 {
    let mut rel: Vec<f64> = mesh
        .vertices
        .positions
        .iter()
        .map(|p| {
            let q = Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64);
            let d = (0..n)
                .map(|i| (q - centre(i)).norm())
                .fold(f64::INFINITY, f64::min);
            surface_distance(p) / d
        })
        .collect();
    rel.sort_by(f64::total_cmp);
    rel[rel.len() * 9 / 10]
}

fn options() -> FusionOptions {
    FusionOptions {
        simplify: None,
        ..FusionOptions::default()
    }
}

#[test]
fn voxel_size_follows_the_depth() {
    let views = street_views(6);
    let (mesh, s) = fuse_depth_maps(&views, &options(), &NoProgress).unwrap();
    let rel = relative_error_90(&mesh, views.len());
    println!(
        "levels {:?}; {} blocks; {} faces; relative error (90%) {rel:.5}",
        s.levels,
        s.blocks,
        mesh.faces.len()
    );
    assert!(
        s.levels.len() >= 3,
        "depths 3..80 span several levels: {:?}",
        s.levels
    );
    assert!(
        rel <= 0.01,
        "90% of the vertices within 1% of their distance: {rel}"
    );
    // The far wall is there, meshed at a coarse level.
    assert!(reaches_far_wall(&mesh, 0.5));

    // One voxel size (level 0's) everywhere needs several times the blocks.
    let mut fixed = options();
    fixed.tsdf.voxel_size = VoxelSize::Absolute(s.voxel_size);
    let (_, f) = fuse_depth_maps(&views, &fixed, &NoProgress).unwrap();
    println!("one voxel size {}: {} blocks", s.voxel_size, f.blocks);
    assert!(
        f.blocks >= 2 * s.blocks,
        "{} blocks vs {} with levels",
        f.blocks,
        s.blocks
    );

    // The levels are a function of space: the view order allocates the same blocks and gives the
    // same mesh (up to the rounding of the running averages).
    let mut reversed = views.clone();
    reversed.reverse();
    let (again, r) = fuse_depth_maps(&reversed, &options(), &NoProgress).unwrap();
    assert_eq!(r.levels, s.levels);
    assert_eq!(again.faces.len(), mesh.faces.len());
    let centroid = |m: &TriMesh| {
        m.vertices.positions.iter().fold(Vector3::zeros(), |a, p| {
            a + Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64)
        }) / m.vertices.positions.len() as f64
    };
    assert!((centroid(&mesh) - centroid(&again)).norm() < 1e-4);
}

/// `n` of the street's views with the far wall's depths uncertain by `far` of the depth (as a
/// stereo pair with little parallax gives), and the rest by 0.05 %.
fn noisy_far_wall(far: f32, n: usize) -> Vec<PosedView> {
    let mut views = street_views(n);
    for v in &mut views {
        let d = v.depth.as_ref().unwrap();
        let mut var = FloatMap::filled(W, H, 1, 0.0);
        for (i, z) in d.data.iter().enumerate() {
            let s = if *z as f64 > 60.0 {
                far * *z
            } else {
                0.0005 * *z
            };
            var.data[i] = s * s;
        }
        v.variance = Some(var);
    }
    views
}

/// Whether some vertex of `mesh` lies within `tolerance` of the far wall's plane.
fn reaches_far_wall(mesh: &TriMesh, tolerance: f64) -> bool {
    mesh.vertices
        .positions
        .iter()
        .any(|p| (p[2] as f64 - FAR_Z).abs() < tolerance)
}

#[test]
fn noisier_far_depths_count_less_but_still_make_the_surface_nothing_better_sees() {
    // 20 % of 80 m is 3–6 truncation bands of the far wall's level: down-weighted, not left out.
    let views = noisy_far_wall(0.2, 6);
    let (mesh, s) = fuse_depth_maps(&views, &options(), &NoProgress).unwrap();
    assert_eq!(s.uncertain_fraction, 0.0, "{s:?}");
    assert!(reaches_far_wall(&mesh, 2.0));
}

#[test]
fn uncertain_far_depths_are_left_out_and_counted() {
    // Uncertain by half the depth: no parallax to speak of.
    let views = noisy_far_wall(0.5, 6);
    let (mesh, s) = fuse_depth_maps(&views, &options(), &NoProgress).unwrap();
    println!(
        "uncertain fraction {:.3}; {} faces",
        s.uncertain_fraction,
        mesh.faces.len()
    );
    assert!(s.uncertain_fraction > 0.01, "{s:?}");
    assert!(!reaches_far_wall(&mesh, 2.0), "the far wall was left out");
    // Kept everything when asked to.
    let mut keep = options();
    keep.tsdf.max_depth_std = 0.0;
    let (all, k) = fuse_depth_maps(&views, &keep, &NoProgress).unwrap();
    assert_eq!(k.uncertain_fraction, 0.0);
    assert!(reaches_far_wall(&all, 0.5));
}

#[test]
fn how_noisy_a_kept_sample_may_be_follows_the_number_of_views_that_average_it() {
    // 35 % of the far wall's depth is 5–10 truncation bands: beyond the 2·K = 6 that four views
    // can average into the band, within the √16 · K = 12 that sixteen views can.
    let few = noisy_far_wall(0.35, 4);
    let (_, s4) = fuse_depth_maps(&few, &options(), &NoProgress).unwrap();
    let many = noisy_far_wall(0.35, 16);
    let (mesh, s16) = fuse_depth_maps(&many, &options(), &NoProgress).unwrap();
    println!(
        "left out: {:.4} of 4 views' samples, {:.4} of 16 views'",
        s4.uncertain_fraction, s16.uncertain_fraction
    );
    assert!(s4.uncertain_fraction > 0.01, "{s4:?}");
    assert!(
        s16.uncertain_fraction < 0.2 * s4.uncertain_fraction,
        "{s16:?}"
    );
    assert!(reaches_far_wall(&mesh, 2.0));
}

#[test]
fn fusion_over_small_tiles_gives_the_one_volume_mesh_with_a_fraction_of_the_blocks() {
    // Marching cubes as it comes (no speck removal, hole filling or simplification), so that
    // the two meshes can be compared vertex for vertex.
    let raw = |tile_blocks: usize| FusionOptions {
        simplify: None,
        min_component_faces: 0,
        max_hole_perimeter_voxels: 0.0,
        tsdf: handheld_mesh::TsdfOptions {
            tile_blocks,
            ..Default::default()
        },
        ..FusionOptions::default()
    };
    let views = street_views(6);
    let (whole, w) = fuse_depth_maps(&views, &raw(1 << 20), &NoProgress).unwrap();
    let (tiled, t) = fuse_depth_maps(&views, &raw(4), &NoProgress).unwrap();
    println!(
        "one tile: {} blocks; tiles of 4 blocks: {} tiles, at most {} blocks at once",
        w.peak_blocks, t.tiles, t.peak_blocks
    );
    assert_eq!(w.tiles, 1);
    assert!(t.tiles > 10, "{} tiles", t.tiles);
    assert_eq!((t.blocks, t.levels.clone()), (w.blocks, w.levels.clone()));
    assert!(
        t.peak_blocks * 4 < w.peak_blocks,
        "{} blocks at once vs {}",
        t.peak_blocks,
        w.peak_blocks
    );
    // The same surface, welded across the tiles: the same vertices (as a set) and faces.
    assert_eq!(tiled.faces.len(), whole.faces.len());
    let sorted = |m: &TriMesh| {
        let mut v: Vec<[u32; 3]> = m
            .vertices
            .positions
            .iter()
            .map(|p| p.map(f32::to_bits))
            .collect();
        v.sort_unstable();
        v
    };
    assert_eq!(sorted(&tiled), sorted(&whole));
    assert_eq!(t.observed_voxels, w.observed_voxels);
}
