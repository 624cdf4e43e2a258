//! The options of the whole standard graph: one typed, serialisable struct per stage. Every default
//! is written once, in the stage's (or its library's) `Default`; front ends read them from here.

use serde::{Deserialize, Serialize};

use crate::stages::dense::DenseStageOptions;
use crate::stages::features::FeaturesStageOptions;
use crate::stages::ingest::IngestStageOptions;
use crate::stages::matches::MatchesStageOptions;
use crate::stages::mesh::MeshStageOptions;
use crate::stages::sparse::SparseStageOptions;

/// Options of every stage of the standard graph.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
#[serde(default)]
pub struct PipelineOptions {
    pub ingest: IngestStageOptions,
    pub features: FeaturesStageOptions,
    pub matches: MatchesStageOptions,
    pub sparse: SparseStageOptions,
    pub dense: DenseStageOptions,
    pub mesh: MeshStageOptions,
    pub render: crate::stages::render::RenderStageOptions,
    /// The augment stage runs (and is in the graph) only when an object is given.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub augment: Option<crate::stages::augment::AugmentOptions>,
}
