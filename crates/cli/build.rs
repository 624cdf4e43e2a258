//! Probes what this crate's real-data and tool-dependent tests need and sets a `has_*` cfg for
//! each need that is met, so that a test whose need is missing shows as ignored, with its reason
//! (with `CI` set, nothing is ignored: the test runs and fails naming what is missing). See
//! `crates/testkit/src/needs.rs`.

#[path = "../testkit/src/needs.rs"]
mod needs;

use needs::Need;

fn main() {
    needs::emit(&[
        ("has_ffmpeg", Need::Ffmpeg),
        ("has_numpy", Need::Numpy),
        ("has_chromium", Need::Chromium),
        ("has_eval_sfm", Need::Tool("eval_sfm.py")),
        ("has_iclnuim", Need::Dataset("iclnuim-5")),
        ("has_herzjesu", Need::Dataset("herzjesu-P8")),
        ("has_temple", Need::Dataset("templeSparseRing")),
        ("has_dino", Need::Dataset("dinoSparseRing")),
        ("has_teddy", Need::Dataset("stereo-teddy")),
        ("has_et", Need::Dataset("bundler-ET")),
    ]);
}
