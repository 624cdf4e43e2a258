//! Surface models: depth-map meshes, TSDF fusion, simplification and texturing (§5.1).
//!
//! Planned in issue #7; this crate currently only reserves its place in the dependency order
//! documented in ARCHITECTURE.md.
