//! Uncalibrated structure and motion: projective reconstruction, self-calibration, metric BA (§3, Table 2).
//!
//! Planned in issue #5; this crate currently only reserves its place in the dependency order
//! documented in ARCHITECTURE.md.
