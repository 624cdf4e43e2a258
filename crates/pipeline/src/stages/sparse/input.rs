//! What the sparse stage reads: the SfM input built from the features and matches stages (the
//! verified pairs of the matches database, or a video's KLT tracks), the keypoints' colours, and
//! the optional multi-view keypoint refinement; and the colouring of the finished model's points.

use std::collections::BTreeMap;

use handheld_core::{ImageId, MetricReconstruction, Progress};
use handheld_features::refine::{
    refine_track_keypoints, KeypointFrame, KeypointRefinementOptions, PairMatches,
    RefinementSummary,
};
use handheld_features::GrayImage;
use handheld_io::database::Database;
use handheld_io::images::{load_image, ImageIngestOptions};
use handheld_io::ingest::InputKind;
use handheld_robust::TwoViewConfiguration;
use handheld_sfm::{SfmImage, SfmInput, SfmPair};
use nalgebra::Vector2;
use rayon::prelude::*;

use crate::error::{PipelineError, Result};
use crate::files::stage;
use crate::manifest::Workspace;
use crate::policy::{camera_key, image_id, quantize_descriptor};

/// Builds the SfM input from the features and matches stages.
pub fn load_input(ws: &Workspace) -> Result<SfmInput> {
    load_input_and_colours(ws).map(|(input, _)| input)
}

/// [`load_input`], and the colours the features stage recorded at each image's keypoints (empty
/// for an image without them: video tracks, or features from an older version).
pub(super) fn load_input_and_colours(ws: &Workspace) -> Result<(SfmInput, Vec<Vec<[u8; 3]>>)> {
    let ingest = ws.read_ingest()?;
    let tracks = ws.read_tracks()?;
    if let Some(t) = &tracks {
        if t.num_frames() != ingest.images.len() {
            return Err(PipelineError::workspace(
                ws.path(stage::FEATURES, crate::files::TRACKS_JSON),
                format!(
                    "{} frames, but ingest has {}; rerun features with --force",
                    t.num_frames(),
                    ingest.images.len()
                ),
            ));
        }
    }
    let (images, colours): (Vec<SfmImage>, Vec<Vec<[u8; 3]>>) = ingest
        .images
        .par_iter()
        .enumerate()
        .map(|(k, img)| {
            let mut f = ws.read_features(k)?;
            let colours = std::mem::take(&mut f.colors);
            let image = SfmImage {
                id: image_id(k),
                name: img.info.name.clone(),
                width: img.info.width,
                height: img.info.height,
                keypoints: f
                    .keypoints
                    .iter()
                    .map(|p| Vector2::new(p[0] as f64, p[1] as f64))
                    .collect(),
                keypoint_scales: f.keypoints.iter().map(|p| p[2]).collect(),
                camera_key: camera_key(&img.info),
                focal_prior_px: img.info.focal_prior_px,
                frame: img.frame,
                track_ids: tracks
                    .as_ref()
                    .map(|t| t.ids[k].clone())
                    .unwrap_or_default(),
                descriptors: quantize_descriptor(&f.descriptors),
                descriptor_dim: f.dim,
            };
            let colours = if colours.len() == image.keypoints.len() {
                colours
            } else {
                Vec::new()
            };
            Ok((image, colours))
        })
        .collect::<Result<Vec<_>>>()?
        .into_iter()
        .unzip();
    let summaries = ws.read_pairs()?;
    let db_path = ws.database_path();
    let db = Database::open(&db_path)?;
    let ids: Vec<u32> = db.images()?.into_iter().map(|(id, _, _)| id).collect();
    if ids.len() != images.len() {
        return Err(PipelineError::workspace(
            &db_path,
            format!(
                "{} images, but ingest has {}; rerun matches with --force",
                ids.len(),
                images.len()
            ),
        ));
    }
    let mut pairs = Vec::new();
    for s in summaries {
        if s.configuration == TwoViewConfiguration::TooFewInliers
            || s.i >= ids.len()
            || s.j >= ids.len()
        {
            continue;
        }
        let Some(g) = db.read_two_view_geometry(ids[s.i], ids[s.j])? else {
            continue;
        };
        pairs.push(SfmPair {
            a: s.i,
            b: s.j,
            matches: g.inliers,
            f: g.f,
            configuration: s.configuration,
            view_distance_px: s.view_distance_px,
        });
    }
    Ok((
        SfmInput {
            images,
            pairs,
            video: ingest.kind == InputKind::Video,
        },
        colours,
    ))
}

/// Registers the keypoints of every track to the track's reference (photos only; see
/// [`handheld_features::refine`]) and replaces the input's keypoints by the refined positions.
pub(super) fn refine_input(
    ws: &Workspace,
    input: &mut SfmInput,
    opts: &KeypointRefinementOptions,
    bars: &dyn Progress,
) -> Result<RefinementSummary> {
    let ingest = ws.read_ingest()?;
    let frames: Vec<Vec<KeypointFrame>> = (0..input.images.len())
        .into_par_iter()
        .map(|k| {
            let f = ws.read_features(k)?;
            Ok(f.keypoints
                .iter()
                .map(|p| KeypointFrame {
                    x: p[0],
                    y: p[1],
                    scale: p[2],
                    orientation: p[3],
                })
                .collect())
        })
        .collect::<Result<_>>()?;
    let pairs: Vec<PairMatches> = input
        .pairs
        .iter()
        .map(|p| PairMatches {
            a: p.a,
            b: p.b,
            matches: &p.matches,
        })
        .collect();
    let load_opts = ImageIngestOptions {
        min_dimension: 1,
        ..Default::default()
    };
    let load = |k: usize| -> Result<GrayImage> {
        let path = &ingest
            .images
            .get(k)
            .ok_or_else(|| {
                PipelineError::workspace(
                    ws.path(stage::INGEST, crate::files::IMAGES_JSON),
                    format!("image {k} is not in the ingest list; rerun with --force"),
                )
            })?
            .info
            .path;
        let img = load_image(path, &load_opts)?;
        Ok(GrayImage::from_dynamic(&img.image))
    };
    bars.start("refine keypoints", 2 * input.images.len() as u64);
    let (refined, summary) = refine_track_keypoints(&frames, &pairs, &load, opts, &|| bars.inc(1))?;
    bars.finish();
    for (im, pts) in input.images.iter_mut().zip(refined) {
        if pts.len() == im.keypoints.len() {
            im.keypoints = pts
                .iter()
                .map(|p| Vector2::new(f64::from(p[0]), f64::from(p[1])))
                .collect();
        }
    }
    Ok(summary)
}

/// Colours every point from the first image that sees it: the colour the features stage recorded
/// at that keypoint, or, for images without recorded colours (video tracks), the image's pixel.
pub(super) fn colorize(
    ws: &Workspace,
    rec: &mut MetricReconstruction,
    colours: &[Vec<[u8; 3]>],
) -> Result<()> {
    let recorded = |id: ImageId| {
        (id.0 as usize)
            .checked_sub(1)
            .filter(|k| image_id(*k) == id)
            .and_then(|k| colours.get(k))
            .filter(|c| !c.is_empty())
    };
    let paths = ws.image_paths()?;
    let opts = ImageIngestOptions {
        min_dimension: 1,
        ..Default::default()
    };
    let views: Vec<(ImageId, String)> = rec
        .views
        .values()
        .filter(|v| recorded(v.id).is_none())
        .map(|v| (v.id, v.name.clone()))
        .collect();
    let imgs: BTreeMap<ImageId, image::RgbImage> = views
        .par_iter()
        .filter_map(|(id, name)| {
            let p = paths.get(name)?;
            load_image(p, &opts).ok().map(|l| (*id, l.image.to_rgb8()))
        })
        .collect();
    for pt in rec.points.values_mut() {
        let Some(el) = pt.track.elements.first() else {
            continue;
        };
        if let Some(c) = recorded(el.image_id).and_then(|c| c.get(el.point2d_idx as usize)) {
            pt.color = *c;
            continue;
        }
        let (Some(img), Some(v)) = (imgs.get(&el.image_id), rec.views.get(&el.image_id)) else {
            continue;
        };
        let xy = v.observations[el.point2d_idx as usize].xy;
        let (x, y) = (
            xy.x.round().clamp(0.0, img.width() as f64 - 1.0) as u32,
            xy.y.round().clamp(0.0, img.height() as f64 - 1.0) as u32,
        );
        pt.color = img.get_pixel(x, y).0;
    }
    Ok(())
}
