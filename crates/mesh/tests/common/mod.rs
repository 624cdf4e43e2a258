//! A small rendered synthetic sequence shared by the integration tests.

#![allow(dead_code)]

use handheld_mesh::{DepthView, ImageView};
use handheld_testkit::{render_sequence, SequenceOptions, SyntheticSequence};

/// Options of `n` frames of the default orbit (seed 7) at `width`×`height`, exact depth, no image
/// noise.
pub fn sequence_options(n: usize, width: u32, height: u32) -> SequenceOptions {
    SequenceOptions {
        seed: 7,
        width,
        height,
        num_frames: n,
        samples_per_axis: 1,
        image_noise_sigma: 0.0,
        ..SequenceOptions::default()
    }
}

/// `n` frames of the default orbit at `width`×`height` (¾ aspect).
pub fn sequence(n: usize, width: u32) -> SyntheticSequence {
    render_sequence(&sequence_options(n, width, width * 3 / 4)).expect("valid sequence options")
}

pub fn depth_views(seq: &SyntheticSequence) -> Vec<DepthView<'_>> {
    (0..seq.depths.len())
        .filter_map(|i| {
            let (camera, pose) = seq.frame(i)?;
            Some(DepthView {
                camera,
                cam_from_world: *pose,
                depth: &seq.depths[i],
                confidence: None,
            })
        })
        .collect()
}

pub fn image_views(seq: &SyntheticSequence) -> Vec<ImageView<'_>> {
    (0..seq.images.len())
        .filter_map(|i| {
            let (camera, pose) = seq.frame(i)?;
            Some(ImageView {
                camera,
                cam_from_world: *pose,
                image: &seq.images[i],
                depth: Some(&seq.depths[i]),
            })
        })
        .collect()
}
