//! A small rendered synthetic sequence shared by the integration tests.

#![allow(dead_code)]

use handheld_mesh::PosedView;
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

/// Every frame as a posed view with its image and exact depth map (no confidence).
pub fn views(seq: &SyntheticSequence) -> Vec<PosedView> {
    (0..seq.depths.len())
        .filter_map(|i| {
            let mut v =
                PosedView::from_posed(format!("frame{i}"), seq.frame(i)?, seq.images[i].clone());
            v.depth = Some(seq.depths[i].clone());
            Some(v)
        })
        .collect()
}

/// [`views`] without copies: the images and depth maps are moved out of `seq`.
pub fn take_views(seq: &mut SyntheticSequence) -> Vec<PosedView> {
    let images = std::mem::take(&mut seq.images);
    let depths = std::mem::take(&mut seq.depths);
    images
        .into_iter()
        .zip(depths)
        .enumerate()
        .filter_map(|(i, (image, depth))| {
            let mut v = PosedView::from_posed(format!("frame{i}"), seq.frame(i)?, image);
            v.depth = Some(depth);
            Some(v)
        })
        .collect()
}
