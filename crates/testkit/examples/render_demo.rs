//! Renders the default synthetic sequence (20 frames, 640×480, 9 rays per pixel), prints the timing and
//! ground-truth statistics, and optionally writes the frames as binary PPM files.
//!
//! `cargo run -p handheld-testkit --example render_demo [output_dir]`

use std::io::Write;
use std::time::Instant;

use handheld_testkit::{render_sequence, SequenceOptions};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let opts = SequenceOptions::default();
    let start = Instant::now();
    let seq = render_sequence(&opts)?;
    let secs = start.elapsed().as_secs_f64();
    println!(
        "{} frames {}x{} at {} rays/pixel in {secs:.2} s; {} landmarks, {} GT points, {} observations, mesh {} triangles",
        seq.images.len(),
        opts.width,
        opts.height,
        opts.samples_per_axis * opts.samples_per_axis,
        seq.scene.landmarks().len(),
        seq.gt.points.len(),
        seq.gt.reprojection_errors().len(),
        seq.mesh.faces.len()
    );
    if let Some(dir) = std::env::args().nth(1) {
        std::fs::create_dir_all(&dir)?;
        for (i, img) in seq.images.iter().enumerate() {
            let mut f = std::fs::File::create(format!("{dir}/frame_{i:04}.ppm"))?;
            write!(f, "P6\n{} {}\n255\n", img.width(), img.height())?;
            f.write_all(img.as_raw())?;
        }
    }
    Ok(())
}
