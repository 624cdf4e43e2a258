//! A glossy sphere's highlight moves with the viewpoint: on held-out views the image-based
//! renderer reproduces it (it blends neighbouring photos), the single-texture mesh does not.
//! Scored against the ground-truth highlight pixels of the held-out photos.

use handheld_eval::bench::{bench_specular, SpecularBenchOptions};

#[test]
fn the_highlight_is_reproduced_by_ibr_and_not_by_the_textured_mesh() {
    let r = bench_specular(&SpecularBenchOptions {
        width: 320,
        frames: 17,
        ..Default::default()
    })
    .expect("specular benchmark");
    assert!(r.highlight_pixels.iter().all(|n| *n >= 50), "{r:?}");
    let psnr = |m: &str| {
        r.scores
            .iter()
            .find(|s| s.method == m)
            .map(|s| s.highlight_psnr)
            .expect("scored")
    };
    assert!(
        psnr("ulr") > psnr("mesh") + 4.0,
        "ULR {} dB vs mesh {} dB on the highlight",
        psnr("ulr"),
        psnr("mesh")
    );
    assert!(psnr("ulr_mesh") > psnr("mesh") + 4.0, "{r:?}");
}
