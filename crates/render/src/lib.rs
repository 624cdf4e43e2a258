//! Rasterisation and image-based rendering of the reconstructed models.
//!
//! Planned in issue #7; this crate currently only reserves its place in the dependency order
//! documented in ARCHITECTURE.md.
