//! Time and peak memory of fusing 11 depth maps of 3072×2048 into a 1 cm TSDF (issue #7, "Memory
//! and time"), then simplifying, texturing and scoring the result against the ground truth.
//!
//! `cargo run -p handheld-mesh --example fuse_large [width] [frames] [voxel_m]` renders the default
//! synthetic orbit (exact depth) with testkit, resets the kernel's peak-RSS counter
//! (`/proc/self/clear_refs`, Linux), and prints the peak after each stage (inputs included).

use std::time::Instant;

#[path = "../tests/common/mod.rs"]
mod common;

use handheld_core::NoProgress;
use handheld_mesh::eval::visible_surface_samples;
use handheld_mesh::{
    evaluate, fuse_depth_maps, texture_mesh, EvalOptions, FusionOptions, TextureOptions, VoxelSize,
};
use handheld_testkit::render_sequence;

/// Peak resident memory in MiB (`VmHWM`), when the platform reports it.
fn peak_mib() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}

fn reset_peak() {
    let _ = std::fs::write("/proc/self/clear_refs", "5");
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let width: u32 = args.get(1).and_then(|a| a.parse().ok()).unwrap_or(3072);
    let frames: usize = args.get(2).and_then(|a| a.parse().ok()).unwrap_or(11);
    let voxel: f64 = args.get(3).and_then(|a| a.parse().ok()).unwrap_or(0.01);
    let opts = common::sequence_options(frames, width, width * 2 / 3);
    let t = Instant::now();
    let mut seq = match render_sequence(&opts) {
        Ok(s) => s,
        Err(e) => {
            eprintln!("cannot render: {e}");
            std::process::exit(1);
        }
    };
    println!(
        "rendered {frames} frames of {width}x{} in {:.1}s (peak {:.0} MiB)",
        width * 2 / 3,
        t.elapsed().as_secs_f64(),
        peak_mib().unwrap_or(f64::NAN)
    );
    let views = common::take_views(&mut seq);
    reset_peak();
    let base = peak_mib().unwrap_or(f64::NAN);
    let mut fopts = FusionOptions::default();
    fopts.tsdf.voxel_size = VoxelSize::Absolute(voxel);
    let t = Instant::now();
    let (mesh, summary) = match fuse_depth_maps(&views, &fopts, &NoProgress) {
        Ok(r) => r,
        Err(e) => {
            eprintln!("fusion failed: {e}");
            std::process::exit(1);
        }
    };
    println!(
        "fused in {:.1}s: {summary:#?}\npeak during fusion {:.0} MiB (inputs held: {base:.0} MiB)",
        t.elapsed().as_secs_f64(),
        peak_mib().unwrap_or(f64::NAN)
    );
    match texture_mesh(&mesh, &views, &TextureOptions::default(), &NoProgress) {
        Ok((_, s)) => println!(
            "textured: {} charts, atlas {}x{} at {:.2} texels/pixel, {} untextured faces, {:.1}s; peak {:.0} MiB",
            s.charts,
            s.atlas_width,
            s.atlas_height,
            s.texel_scale,
            s.untextured_faces,
            s.seconds,
            peak_mib().unwrap_or(f64::NAN)
        ),
        Err(e) => eprintln!("texturing failed: {e}"),
    }
    let size = seq.scene.extent();
    let t = Instant::now();
    let samples = visible_surface_samples(&views, 16).unwrap_or_default();
    let eval = EvalOptions {
        accuracy_fraction: 0.9,
        completeness_threshold: 0.01 * size,
        sample_spacing: 2.0 * voxel,
    };
    match evaluate(&mesh, &seq.mesh, &samples, &eval) {
        Ok(s) => println!(
            "accuracy@90 {:.4} ({:.3}% of the scene size {size:.2}), completeness@1% {:.2}% ({:.1}s)",
            s.accuracy,
            100.0 * s.accuracy / size,
            100.0 * s.completeness,
            t.elapsed().as_secs_f64()
        ),
        Err(e) => eprintln!("evaluation failed: {e}"),
    }
}
