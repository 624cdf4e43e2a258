//! Photos are reconstructed in an order fixed by their content, not by their file names.
//!
//! Every choice the SfM makes breaks ties and draws its random samples in image order: the order
//! of the 2D–3D correspondences a resection samples, which of two equally good views is added
//! first, the order of the parameters in bundle adjustment. Photos have no order of their own, so
//! a model that changes when the files are renamed is a model that depends on chance. The input
//! is therefore put in an order given by a key of each image's content (its keypoints and
//! descriptors) and its ids renumbered in that order; the models are given their original ids
//! back at the end. Renaming or shuffling the files then gives the same models, bit for bit.
//!
//! Video keeps its frame order, which is the capture order and carries meaning (key-frames, the
//! sequential window, in-between frames).

use std::collections::BTreeMap;

use handheld_core::{ImageId, MetricReconstruction};

use crate::input::{SfmImage, SfmInput, SfmPair};

/// The input in content order, and the original id of each canonical id.
pub(crate) struct Canonical {
    pub input: SfmInput,
    original: BTreeMap<ImageId, ImageId>,
}

/// FNV-1a over an image's keypoint positions and descriptor bytes: the same for the same image
/// whatever it is called.
pub(crate) fn content_key(im: &SfmImage) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    let mut eat = |b: u64| {
        for k in 0..8 {
            h ^= (b >> (8 * k)) & 0xff;
            h = h.wrapping_mul(0x0100_0000_01b3);
        }
    };
    eat(im.keypoints.len() as u64);
    eat(u64::from(im.width) << 32 | u64::from(im.height));
    for k in im.keypoints.iter().take(512) {
        eat(k.x.to_bits());
        eat(k.y.to_bits());
    }
    for &d in im.descriptors.iter().take(4096) {
        eat(u64::from(d));
    }
    h
}

impl Canonical {
    /// `None` for video (kept in frame order).
    pub fn new(input: &SfmInput) -> Option<Self> {
        if input.video {
            return None;
        }
        let n = input.images.len();
        let keys: Vec<u64> = input.images.iter().map(content_key).collect();
        let mut order: Vec<usize> = (0..n).collect();
        // The name only separates identical images.
        order.sort_by(|&a, &b| {
            keys[a]
                .cmp(&keys[b])
                .then_with(|| input.images[a].name.cmp(&input.images[b].name))
        });
        let mut new_index = vec![0usize; n];
        for (k, &old) in order.iter().enumerate() {
            new_index[old] = k;
        }
        let mut original = BTreeMap::new();
        let images = order
            .iter()
            .enumerate()
            .map(|(k, &old)| {
                let id = ImageId(k as u32 + 1);
                original.insert(id, input.images[old].id);
                SfmImage {
                    id,
                    ..input.images[old].clone()
                }
            })
            .collect();
        let mut pairs: Vec<SfmPair> = input
            .pairs
            .iter()
            .map(|p| {
                let (a, b) = (new_index[p.a], new_index[p.b]);
                if a < b {
                    SfmPair { a, b, ..p.clone() }
                } else {
                    SfmPair {
                        a: b,
                        b: a,
                        matches: p.matches.iter().map(|&(i, j)| (j, i)).collect(),
                        f: p.f.map(|f| f.transpose()),
                        ..p.clone()
                    }
                }
            })
            .collect();
        pairs.sort_by_key(|p| (p.a, p.b));
        Some(Self {
            input: SfmInput {
                images,
                pairs,
                video: false,
            },
            original,
        })
    }

    /// Gives a model built on the canonical input its original image ids back.
    pub fn restore(&self, rec: &mut MetricReconstruction) {
        let id = |i: ImageId| self.original.get(&i).copied().unwrap_or(i);
        rec.views = std::mem::take(&mut rec.views)
            .into_values()
            .map(|mut v| {
                v.id = id(v.id);
                (v.id, v)
            })
            .collect();
        for p in rec.points.values_mut() {
            for el in &mut p.track.elements {
                el.image_id = id(el.image_id);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use handheld_robust::TwoViewConfiguration;
    use nalgebra::{Matrix3, Vector2};

    fn image(id: u32, x: f64) -> SfmImage {
        SfmImage {
            id: ImageId(id),
            name: format!("{id}.jpg"),
            width: 100,
            height: 80,
            keypoints: vec![Vector2::new(x, 1.0), Vector2::new(2.0, x)],
            keypoint_scales: vec![1.0; 2],
            camera_key: String::new(),
            focal_prior_px: None,
            frame: None,
            track_ids: Vec::new(),
            descriptors: Vec::new(),
            descriptor_dim: 0,
        }
    }

    #[test]
    fn the_order_follows_the_content_and_pairs_are_reoriented() {
        let f = Matrix3::new(0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0);
        let input = SfmInput {
            images: vec![image(1, 10.0), image(2, 20.0), image(3, 30.0)],
            pairs: vec![SfmPair {
                a: 0,
                b: 2,
                matches: vec![(0, 1)],
                f: Some(f),
                configuration: TwoViewConfiguration::General,
                view_distance_px: None,
            }],
            video: false,
        };
        // The same images under other names, in another order.
        let mut shuffled = input.clone();
        shuffled.images.reverse();
        for (k, im) in shuffled.images.iter_mut().enumerate() {
            im.id = ImageId(k as u32 + 1);
            im.name = format!("renamed{k}.jpg");
        }
        // Image 1 is now at index 2 and image 3 at index 0: the pair is stored the other way round.
        shuffled.pairs[0].a = 0;
        shuffled.pairs[0].b = 2;
        shuffled.pairs[0].matches = vec![(1, 0)];
        shuffled.pairs[0].f = Some(f.transpose());
        let (c1, c2) = (
            Canonical::new(&input).unwrap(),
            Canonical::new(&shuffled).unwrap(),
        );
        let kp =
            |c: &Canonical| -> Vec<_> { c.input.images.iter().map(|i| i.keypoints[0]).collect() };
        assert_eq!(kp(&c1), kp(&c2));
        let (p1, p2) = (&c1.input.pairs[0], &c2.input.pairs[0]);
        assert_eq!(
            (p1.a, p1.b, &p1.matches, p1.f),
            (p2.a, p2.b, &p2.matches, p2.f)
        );
        // Ids come back: the canonical image holding image 3's content is restored to id 3.
        let k3 = c1
            .input
            .images
            .iter()
            .position(|i| i.name == "3.jpg")
            .unwrap();
        assert_eq!(c1.original[&ImageId(k3 as u32 + 1)], ImageId(3));
    }

    #[test]
    fn video_keeps_its_frame_order() {
        let input = SfmInput {
            images: vec![image(1, 10.0), image(2, 20.0)],
            pairs: Vec::new(),
            video: true,
        };
        assert!(Canonical::new(&input).is_none());
    }
}
