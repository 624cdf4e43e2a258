//! `handheld demo`: maps the arguments onto `handheld_eval::DemoOptions`, runs the demo (render,
//! reconstruct, score against the ground truth) and prints its report.

use anyhow::Result;
use handheld_eval::DemoOptions;

use crate::args::{DemoArgs, GlobalArgs};
use crate::ui::{print_result, Bars};

pub fn run(a: &DemoArgs, g: &GlobalArgs, bars: &Bars) -> Result<()> {
    let o = DemoOptions {
        output: a.output.clone(),
        frames: a.frames,
        width: a.width,
        height: a.height,
        seed: a.seed,
        path: a.path,
        force: a.force,
        aspect_ratio: a.aspect_ratio,
        video: a.video,
        augment: a.augment,
        scene: a.scene,
        fov_deg: a.fov,
        k1: a.k1,
        crf: a.crf,
        rolling_shutter: a.rolling_shutter,
        exposure: a.exposure,
        until: a.until.clone(),
    };
    let r = handheld_eval::run_demo(&o, bars)?;
    let value = serde_json::to_value(&r)?;
    let acc = &value["accuracy"];
    let stages: Vec<String> = r
        .stages
        .iter()
        .map(|s| format!("{} ({}, {:.2} s)", s.stage, s.status, s.seconds))
        .collect();
    let mut human = format!(
        "demo: {} frames {}×{} in {}\n  rendering + ground truth: {:.2} s\n  stages: {}\n  matching accuracy: {}\n  camera accuracy (uncalibrated): {}\n  depth accuracy: {}\n  mesh accuracy: {}",
        r.frames,
        r.width,
        r.height,
        r.demo.display(),
        r.render_seconds,
        stages.join(", "),
        acc["matching"],
        acc["sparse"],
        acc["dense"],
        acc["mesh"],
    );
    if a.augment {
        human.push_str(&format!(
            "\n  augmented video (object vs exact cameras): {}",
            acc["augment"]
        ));
    }
    print_result(g, &value, &human);
    Ok(())
}
