//! Bad input gives a clear error naming the problem, never an empty mesh reported as success.

mod common;

use handheld_core::{FloatMap, NoProgress, PosedCamera, Rigid3};
use handheld_mesh::{
    fuse_depth_maps, mesh_from_depth_map, texture_mesh, FusionOptions, MeshError, PosedView,
    SingleMeshOptions, TextureOptions, VoxelSize,
};
use nalgebra::Vector3;

fn opts() -> FusionOptions {
    let mut o = FusionOptions::default();
    o.tsdf.voxel_size = VoxelSize::Absolute(0.04);
    o
}

#[test]
fn wrong_sizes_and_empty_maps_are_named() {
    let seq = common::sequence(3, 160);
    let views = common::views(&seq);
    let small = FloatMap::filled(80, 60, 1, 3.0);
    let mut bad = views.clone();
    bad[1].depth = Some(small.clone());
    let err = fuse_depth_maps(&bad, &opts(), &NoProgress).unwrap_err();
    assert!(
        matches!(
            err,
            MeshError::SizeMismatch {
                view: 1,
                what: "depth map",
                got_w: 80,
                cam_w: 160,
                ..
            }
        ),
        "{err}"
    );
    println!("{err}");
    let mut bad = views.clone();
    bad[2].confidence = Some(small.clone());
    let err = fuse_depth_maps(&bad, &opts(), &NoProgress).unwrap_err();
    assert!(
        matches!(
            err,
            MeshError::SizeMismatch {
                view: 2,
                what: "confidence map",
                ..
            }
        ),
        "{err}"
    );
    let empty = FloatMap::filled(160, 120, 1, f32::NAN);
    let mut bad = views.clone();
    bad[0].depth = Some(empty.clone());
    // One view without depth (all its pairs failed) is left out and named; the others are fused.
    let (mesh, summary) = fuse_depth_maps(&bad, &opts(), &NoProgress).unwrap();
    assert!(!mesh.faces.is_empty());
    assert_eq!(summary.views, views.len() - 1);
    assert_eq!(summary.views_without_depth, vec![bad[0].name.clone()]);
    let err = mesh_from_depth_map(&bad[0], &SingleMeshOptions::default(), &NoProgress).unwrap_err();
    assert_eq!(err, MeshError::EmptyDepth { view: 0 });
    // A set where no view has depth is an error.
    let mut all_empty = views.clone();
    for v in &mut all_empty {
        v.depth = Some(empty.clone());
    }
    let err = fuse_depth_maps(&all_empty, &opts(), &NoProgress).unwrap_err();
    assert_eq!(err, MeshError::EmptyDepth { view: 0 });
    let err = fuse_depth_maps(&[], &opts(), &NoProgress).unwrap_err();
    assert!(matches!(err, MeshError::NoViews { .. }));
    let mut bad = views.clone();
    bad[1].depth = None;
    let err = fuse_depth_maps(&bad, &opts(), &NoProgress).unwrap_err();
    assert_eq!(
        err,
        MeshError::MissingMap {
            view: 1,
            what: "depth map"
        }
    );
    let two_channels = FloatMap::filled(160, 120, 2, 1.0);
    let mut bad = views.clone();
    bad[0].depth = Some(two_channels);
    let err = fuse_depth_maps(&bad, &opts(), &NoProgress).unwrap_err();
    assert!(
        matches!(err, MeshError::MalformedMap { view: 0, .. }),
        "{err}"
    );
}

#[test]
fn depth_maps_that_do_not_overlap_are_an_error() {
    let seq = common::sequence(3, 160);
    let views = common::views(&seq);
    // The second camera moved 50 m back along its optical axis: its depths describe a surface far
    // from the first one's, so no voxel is seen near a surface by both.
    let back = Rigid3::translation(0.0, 0.0, 50.0) * views[1].posed.cam_from_world;
    let moved = vec![
        views[0].clone(),
        PosedView {
            posed: PosedCamera::new(views[1].camera().clone(), back),
            ..views[1].clone()
        },
    ];
    let err = fuse_depth_maps(&moved, &opts(), &NoProgress).unwrap_err();
    println!("{err}");
    assert_eq!(
        err,
        MeshError::NoOverlap {
            views: 2,
            min_observations: 2
        }
    );
    // Non-finite poses and invalid options are named too.
    let nan = Rigid3::new(Vector3::new(f64::NAN, 0.0, 0.0), Vector3::zeros());
    let bad = vec![PosedView {
        posed: PosedCamera::new(views[0].camera().clone(), nan),
        ..views[0].clone()
    }];
    assert!(matches!(
        fuse_depth_maps(&bad, &opts(), &NoProgress),
        Err(MeshError::BadCamera { view: 0, .. })
    ));
    let mut o = opts();
    o.tsdf.voxel_size = VoxelSize::Absolute(-1.0);
    let err = fuse_depth_maps(&views, &o, &NoProgress).unwrap_err();
    assert!(
        matches!(
            err,
            MeshError::InvalidOption {
                option: "voxel_size",
                ..
            }
        ),
        "{err}"
    );
    // A voxel size far too small for a tile hits the block budget instead of eating memory.
    let mut o = opts();
    o.tsdf.voxel_size = VoxelSize::Absolute(0.001);
    o.tsdf.max_blocks = 10_000;
    o.tsdf.tile_blocks = 1 << 20;
    let err = fuse_depth_maps(&views, &o, &NoProgress).unwrap_err();
    assert!(
        matches!(err, MeshError::TooManyBlocks { limit: 10_000, .. }),
        "{err}"
    );
}

#[test]
fn texturing_rejects_mismatched_images_and_foreign_views() {
    let seq = common::sequence(3, 160);
    let views = common::views(&seq);
    let (mesh, _) = fuse_depth_maps(&views, &opts(), &NoProgress).unwrap();
    let images = views;
    let bad = vec![PosedView {
        image: image::RgbImage::new(10, 10),
        ..images[0].clone()
    }];
    let err = texture_mesh(&mesh, &bad, &TextureOptions::default(), &NoProgress).unwrap_err();
    assert!(
        matches!(err, MeshError::SizeMismatch { what: "image", .. }),
        "{err}"
    );
    // Cameras looking away from the mesh see none of it.
    let turned = Rigid3::rotation(Vector3::new(0.0, std::f64::consts::PI, 0.0))
        * images[0].posed.cam_from_world;
    let away = vec![PosedView {
        posed: PosedCamera::new(images[0].camera().clone(), turned),
        depth: None,
        ..images[0].clone()
    }];
    let err = texture_mesh(&mesh, &away, &TextureOptions::default(), &NoProgress).unwrap_err();
    assert!(
        matches!(
            err,
            MeshError::EmptyResult {
                stage: "texturing",
                ..
            }
        ),
        "{err}"
    );
}
