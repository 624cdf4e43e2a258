//! Multi-view geometry solvers (F, H, triangulation, resection, rectification maps) of paper §1.1–§3.
//!
//! Planned in issue #3; this crate currently only reserves its place in the dependency order
//! documented in ARCHITECTURE.md.
