//! Generic RANSAC (Estimator/Sampler/Consensus), LO-RANSAC and the T(d,d) test of paper §2.2.
//!
//! Planned in issue #3; this crate currently only reserves its place in the dependency order
//! documented in ARCHITECTURE.md.
