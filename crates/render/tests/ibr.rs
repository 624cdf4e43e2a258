//! Image-based rendering on a synthetic sequence with exact ground truth: a held-out frame is
//! rendered from the others (their images and ground-truth depth maps) and compared with its
//! photo.

use handheld_core::PosedView;
use handheld_render::{quality, IbrMethod, IbrOptions, IbrScene, Renderer};
use handheld_testkit::path::PathOptions;
use handheld_testkit::render::render_sequence;
use handheld_testkit::sequence::SequenceOptions;

fn views(seq: &handheld_testkit::render::SyntheticSequence) -> Vec<PosedView> {
    (0..seq.images.len())
        .map(|i| {
            let frame = seq.frame(i).unwrap();
            let mut v = PosedView::from_posed(format!("{i}"), frame, seq.images[i].clone());
            v.depth = Some(seq.depths[i].clone());
            v
        })
        .collect()
}

/// The three geometry levels improve in the paper's order on a held-out frame of an orbit, the
/// subdivided geometry is close to the photo, and every method covers the frame.
#[test]
fn held_out_frame_improves_with_the_geometry_level() {
    let opts = SequenceOptions {
        seed: 3,
        width: 200,
        height: 150,
        num_frames: 9,
        path: PathOptions::orbit(9),
        samples_per_axis: 2,
        ..Default::default()
    };
    let seq = render_sequence(&opts).unwrap();
    let mut all = views(&seq);
    let held = all.remove(4);
    let points: Vec<_> = seq.gt.points.values().map(|p| p.xyz).collect();
    let scene = IbrScene::new(&all, &points).unwrap();
    let mut renderer = Renderer::new();
    let mut ibr = IbrOptions::default();
    if let Ok(v) = std::env::var("IBR_MIN_TRI") {
        ibr.min_triangle_px = v.parse().unwrap();
        ibr.max_subdivision = 9;
    }
    if let Ok(v) = std::env::var("IBR_OCC") {
        ibr.occlusion_tolerance = v.parse().unwrap();
    }
    let mut psnr = Vec::new();
    for m in IbrMethod::ALL {
        let (r, s) = renderer.render(&scene, &held.posed, m, &ibr).unwrap();
        let q = quality(&r.image, &held.image, &r.covered);
        println!(
            "{:>10}: PSNR {:.2} dB, SSIM {:.3}, coverage {:.3}, {} cameras, {} triangles, {} leaves",
            m.name(),
            q.psnr,
            q.ssim,
            q.coverage,
            s.cameras,
            s.triangles,
            s.leaves
        );
        if let Ok(dir) = std::env::var("IBR_DEBUG_DIR") {
            let (w, h) = (held.image.width(), held.image.height());
            let mut strip = image::RgbImage::new(2 * w, h);
            image::imageops::replace(&mut strip, &held.image, 0, 0);
            image::imageops::replace(&mut strip, &r.image, i64::from(w), 0);
            strip.save(format!("{dir}/{}.png", m.name())).unwrap();
        }
        if matches!(m, IbrMethod::Subdivided | IbrMethod::Ulr) {
            assert!(q.coverage > 0.95, "{}: coverage {}", m.name(), q.coverage);
        }
        psnr.push(q.psnr);
    }
    // The orbit's neighbours are beside the held-out camera: their centres project far outside
    // its image, the support mesh is the two triangles of the image corners, and one plane per
    // triangle is no better than the fixed plane. Subdivision is what follows the scene.
    assert!(
        psnr[2] > psnr[0] + 5.0,
        "subdivided {} vs plane {}",
        psnr[2],
        psnr[0]
    );
    assert!(
        psnr[2] > psnr[1] + 5.0,
        "subdivided {} vs planes {}",
        psnr[2],
        psnr[1]
    );
    assert!(psnr[2] > 23.5, "subdivided {}", psnr[2]);
    assert!(psnr[3] > 24.5, "ulr {}", psnr[3]);
}
