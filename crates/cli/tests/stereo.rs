//! `handheld stereo` on the Middlebury teddy pair (issue #6's Done-when 1): the disparity it writes
//! is scored against the ground truth as `eval_stereo.py` does (a missing estimate counts as bad).

mod common;
use common::*;

use std::path::Path;

/// bad1 (%) of a PFM disparity against a Middlebury GT (`value / 4`, 0 = unknown).
fn bad1(est: &Path, gt: &Path) -> f64 {
    let d = handheld_io::pfm::read_pfm(est).unwrap();
    let g = image::open(gt).unwrap().to_luma8();
    assert_eq!((d.width as u32, d.height as u32), g.dimensions());
    let (mut n, mut bad) = (0usize, 0usize);
    for (i, v) in g.as_raw().iter().enumerate() {
        if *v == 0 {
            continue;
        }
        n += 1;
        let e = d.data[i];
        if !(e.is_finite() && e > 0.0) || (e - f32::from(*v) / 4.0).abs() > 1.0 {
            bad += 1;
        }
    }
    100.0 * bad as f64 / n as f64
}

#[test]
#[cfg_attr(
    not(has_teddy),
    ignore = "needs ../shared/datasets/stereo-teddy (missing)"
)]
fn teddy_sgm_and_dp_meet_the_bad1_targets() {
    let data = dataset("stereo-teddy");
    let dir = tempfile::tempdir().unwrap();
    for (method, limit) in [("sgm", 15.0), ("dp", 25.0)] {
        let out = dir.path().join(format!("{method}.pfm"));
        let o = handheld(&[
            "stereo",
            "--left",
            data.join("im2.png").to_str().unwrap(),
            "--right",
            data.join("im6.png").to_str().unwrap(),
            "--max-disparity",
            "63",
            "--method",
            method,
            "-o",
            out.to_str().unwrap(),
            "--quiet",
        ]);
        assert!(o.status.success(), "{}", stderr(&o));
        let b = bad1(&out, &data.join("disp2.pgm"));
        assert!(b <= limit, "{method}: bad1 {b:.2} % > {limit} %");
    }
}

#[test]
fn stereo_rejects_bad_input() {
    let dir = tempfile::tempdir().unwrap();
    let l = dir.path().join("l.png");
    let r = dir.path().join("r.png");
    write_image(&l, 1);
    image::RgbImage::new(10, 10).save(&r).unwrap();
    let out = dir.path().join("d.pfm");
    let run = |max: &str, right: &Path| {
        handheld(&[
            "stereo",
            "--left",
            l.to_str().unwrap(),
            "--right",
            right.to_str().unwrap(),
            "--max-disparity",
            max,
            "-o",
            out.to_str().unwrap(),
        ])
    };
    // Different sizes.
    let o = run("16", &r);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("differ in size"), "{}", stderr(&o));
    // Empty disparity range.
    let o = run("-5", &l);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("disparity"), "{}", stderr(&o));
    // Missing file.
    let o = run("16", &dir.path().join("nope.png"));
    assert!(!o.status.success());
    assert!(stderr(&o).contains("nope.png"), "{}", stderr(&o));
    assert!(!stderr(&o).contains("panicked"));
    assert!(!out.exists(), "no output on failure");
}
