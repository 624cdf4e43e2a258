//! Sparse Levenberg–Marquardt bundle adjustment with Schur complement, projective and metric (§3.3, §3.4).
//!
//! Planned in issue #4; this crate currently only reserves its place in the dependency order
//! documented in ARCHITECTURE.md.
