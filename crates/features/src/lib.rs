//! Feature detection, KLT tracking, descriptor matching and two-view verification of paper §2.
//!
//! Planned in issue #3; this crate currently only reserves its place in the dependency order
//! documented in ARCHITECTURE.md.
