//! What one merge records for the summary ([`MergeRecord`]), in a leaf that the summary and the
//! merge both import.

use serde::Serialize;

/// One merge, for the summary.
#[derive(Clone, Debug, Default, Serialize, serde::Deserialize)]
pub struct MergeRecord {
    /// Views of the model merged into this one.
    pub views_added: usize,
    /// 3D–3D correspondences found through the verified pairs, and those the similarity explains.
    pub correspondences: usize,
    pub inliers: usize,
    /// 2D–3D links (keypoints of one model's views matched to the other model's points) and those
    /// the similarity explains; zero when the 3D–3D correspondences sufficed.
    pub sightings: usize,
    pub sighting_inliers: usize,
    /// Verified pairs between the two pieces strong enough to fix a relative rotation, and the
    /// merged model's weighted-median disagreement with them (degrees); none usable means the
    /// merge rests on the correspondences alone.
    pub cross_pairs: usize,
    pub cross_disagreement_deg: Option<f64>,
    /// Scale of the similarity that maps the merged model into this one's frame.
    pub scale: f64,
}

impl MergeRecord {
    /// The record with the check across the pieces (`consistency::across`) filled in.
    pub(super) fn across(mut self, across: Option<(f64, usize)>) -> Self {
        self.cross_disagreement_deg = across.map(|x| x.0);
        self.cross_pairs = across.map_or(0, |x| x.1);
        self
    }
}
