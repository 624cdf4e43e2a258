//! Dense surface estimation: rectification, stereo and multi-view linking (§4).
//!
//! Planned in issue #6; this crate currently only reserves its place in the dependency order
//! documented in ARCHITECTURE.md.
