//! Adding a stage is one file plus one line: this file defines a stage (its name, what it reads,
//! its options and their check, its summary and its body), and one `register` line puts it after
//! the standard graph. The test checks that its reads, options, summary, warnings and outputs all
//! work through the runner, and that optional inputs ("reads when present") behave as documented.

use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};

use handheld_core::NoProgress;
use handheld_pipeline::files::stage;
use handheld_pipeline::warning::code;
use handheld_pipeline::{
    Pipeline, PipelineError, PipelineOptions, Produced, Stage, StageContext, StageStatus, Warning,
    Workspace,
};
use image::{Rgb, RgbImage};
use serde::{Deserialize, Serialize};

// ---- the one file: a stage that measures the photos' brightness -------------------------------

/// Options of the brightness stage.
#[derive(Clone, Debug, Serialize)]
struct BrightnessOptions {
    /// Images darker than this mean level (0–255) are called out.
    dark_below: f64,
}

#[derive(Debug, Serialize, Deserialize, PartialEq)]
struct BrightnessSummary {
    images: usize,
    mean_level: f64,
    dark: usize,
}

struct Brightness {
    options: BrightnessOptions,
}

impl Stage for Brightness {
    type Options = BrightnessOptions;
    type Summary = BrightnessSummary;

    const NAME: &'static str = "brightness";
    const READS: &'static [&'static str] = &[stage::INGEST];
    const ABOUT: &'static str = "mean brightness of every photo";

    fn options(&self) -> &BrightnessOptions {
        &self.options
    }

    fn validate(&self) -> handheld_pipeline::Result<()> {
        let d = self.options.dark_below;
        if !(0.0..=255.0).contains(&d) {
            return Err(PipelineError::option(
                "dark_below",
                format!("must be in 0..=255, got {d}"),
            ));
        }
        Ok(())
    }

    fn run(
        &self,
        ctx: &StageContext,
        dir: &Path,
    ) -> handheld_pipeline::Result<Produced<BrightnessSummary>> {
        let ingest = ctx.ws.read_ingest()?;
        let mut levels = Vec::new();
        for img in &ingest.images {
            let im = image::open(&img.info.path)
                .map_err(|e| PipelineError::workspace(&img.info.path, e.to_string()))?
                .to_luma8();
            let sum: f64 = im.pixels().map(|p| f64::from(p.0[0])).sum();
            levels.push((
                img.info.name.clone(),
                sum / f64::from(im.width() * im.height()),
            ));
        }
        handheld_pipeline::files::write_json(&dir.join("levels.json"), &levels)?;
        let dark: Vec<&String> = levels
            .iter()
            .filter(|l| l.1 < self.options.dark_below)
            .map(|l| &l.0)
            .collect();
        let warnings = dark
            .iter()
            .map(|n| {
                Warning::new(code::IMAGE, format!("{n} is dark"))
                    .advice("expose longer, or light the scene")
            })
            .collect();
        let summary = BrightnessSummary {
            images: levels.len(),
            mean_level: levels.iter().map(|l| l.1).sum::<f64>() / levels.len().max(1) as f64,
            dark: dark.len(),
        };
        Ok(Produced::new(vec!["levels.json".into()], summary).warn(warnings))
    }
}

// ---- the test ----------------------------------------------------------------------------------

/// Three photos of known mean level: 40, 120, 200.
fn photos(dir: &Path) -> [f64; 3] {
    let levels = [40u8, 120, 200];
    for (k, l) in levels.iter().enumerate() {
        // A checkerboard around the level, so the photos are not blank.
        let img = RgbImage::from_fn(160, 120, |x, y| {
            let v = if (x / 8 + y / 8) % 2 == 0 {
                l - 20
            } else {
                l + 20
            };
            Rgb([v, v, v])
        });
        handheld_io::ingest::write_png(&dir.join(format!("p{k}.png")), &img).expect("write");
    }
    levels.map(f64::from)
}

fn graph(input: &Path, dark_below: f64) -> handheld_pipeline::Result<Pipeline> {
    let mut p = Pipeline::standard(input, &PipelineOptions::default())?;
    p.register(Brightness {
        options: BrightnessOptions { dark_below },
    })?; // the one line
    Ok(p)
}

#[test]
fn a_stage_in_one_file_reads_its_inputs_and_records_its_options_summary_and_warnings() {
    let dir = tempfile::tempdir().expect("temp dir");
    let input = dir.path().join("photos");
    let levels = photos(&input);
    let ws = Workspace::open(&dir.path().join("ws")).expect("workspace");

    let p = graph(&input, 50.0).expect("graph");
    assert!(p.names().contains(&"brightness"));
    // It needs only ingest: nothing else runs.
    assert_eq!(
        p.plan("brightness").expect("plan"),
        ["ingest", "brightness"]
    );
    let reports = p
        .run(&ws, Some("brightness"), false, &NoProgress)
        .expect("run");
    let r = reports.last().expect("a report");
    assert_eq!(r.status, StageStatus::Ran);
    // The summary, typed, from the manifest; and the runner's summary.json.
    let s: BrightnessSummary = ws.summary("brightness").expect("read").expect("summary");
    let want = levels.iter().sum::<f64>() / 3.0;
    assert_eq!(s.images, 3);
    assert!(
        (s.mean_level - want).abs() < 0.5,
        "{} vs {want}",
        s.mean_level
    );
    assert_eq!(s.dark, 1);
    assert!(ws.path("brightness", "summary.json").exists());
    assert!(ws.path("brightness", "levels.json").exists());
    // The warning is typed.
    let m = ws.manifest("brightness").expect("manifest");
    assert_eq!(m.warnings.len(), 1);
    assert_eq!(m.warnings[0].code, code::IMAGE);
    assert_eq!(m.warnings[0].message, "p0.png is dark");
    assert!(m.outputs.iter().any(|o| o == "summary.json"));

    // Same options: skipped. Other options: run again, with the new result.
    let again = p
        .run(&ws, Some("brightness"), false, &NoProgress)
        .expect("run");
    assert_eq!(again.last().expect("report").status, StageStatus::UpToDate);
    let p = graph(&input, 150.0).expect("graph");
    let again = p
        .run(&ws, Some("brightness"), false, &NoProgress)
        .expect("run");
    assert_eq!(again.last().expect("report").status, StageStatus::Ran);
    let s: BrightnessSummary = ws.summary("brightness").expect("read").expect("summary");
    assert_eq!(s.dark, 2);

    // An option out of range is refused when the stage is registered, naming the option.
    let err = graph(&input, 300.0).err().expect("refused");
    assert_eq!(err.invalid_option(), Some("dark_below"));

    // The report lists the graph's stages, the new one included.
    let report =
        handheld_pipeline::report::write_workspace_report(&ws, &p.names()).expect("report");
    assert!(report.missing.iter().any(|m| m == "sparse"));
    assert!(!report.missing.iter().any(|m| m == "brightness"));
    let html = std::fs::read_to_string(&report.html).expect("html");
    assert!(
        html.contains("p0.png is dark"),
        "the stage's warning is in the report"
    );
}

// ---- optional inputs ---------------------------------------------------------------------------

static RUNS: AtomicUsize = AtomicUsize::new(0);

/// A stage that fails when told to.
struct Maybe {
    fail: bool,
}

impl Stage for Maybe {
    type Options = bool;
    type Summary = ();
    const NAME: &'static str = "maybe";
    const READS: &'static [&'static str] = &[];
    const ABOUT: &'static str = "succeeds or fails";
    fn options(&self) -> &bool {
        &self.fail
    }
    fn run(&self, _: &StageContext, _: &Path) -> handheld_pipeline::Result<Produced<()>> {
        if self.fail {
            return Err(PipelineError::Graph("told to fail".into()));
        }
        Ok(Produced::new(Vec::new(), ()))
    }
}

/// A stage that uses `maybe` when it is there, and says whether it was.
struct User;

impl Stage for User {
    type Options = ();
    type Summary = bool;
    const NAME: &'static str = "user";
    const READS: &'static [&'static str] = &[];
    const READS_IF_PRESENT: &'static [&'static str] = &["maybe"];
    const ABOUT: &'static str = "uses maybe when present";
    fn options(&self) -> &() {
        &()
    }
    fn run(&self, ctx: &StageContext, _: &Path) -> handheld_pipeline::Result<Produced<bool>> {
        RUNS.fetch_add(1, Ordering::SeqCst);
        Ok(Produced::new(Vec::new(), ctx.has("maybe")))
    }
}

fn pair(fail: bool) -> Pipeline {
    let mut p = Pipeline::new();
    p.register(Maybe { fail }).expect("maybe");
    p.register(User).expect("user");
    p
}

#[test]
fn an_optional_input_runs_first_and_its_failure_does_not_stop_the_stage() {
    let dir = tempfile::tempdir().expect("temp dir");
    let ws = Workspace::open(dir.path()).expect("workspace");
    assert_eq!(pair(true).plan("user").expect("plan"), ["maybe", "user"]);

    // `maybe` fails: `user` runs without it, and the run (for `user`) succeeds.
    let r = pair(true)
        .run(&ws, Some("user"), false, &NoProgress)
        .expect("the optional input's failure is not the run's");
    assert_eq!(r.len(), 1);
    assert_eq!(r[0].summary, serde_json::json!(false));
    // Asked for everything, the failure is reported (after `user` ran).
    let before = RUNS.load(Ordering::SeqCst);
    assert!(pair(true).run(&ws, None, true, &NoProgress).is_err());
    assert_eq!(RUNS.load(Ordering::SeqCst), before + 1);

    // `maybe` now succeeds: `user`'s fingerprint covers it, so it runs again and sees it.
    let r = pair(false)
        .run(&ws, Some("user"), false, &NoProgress)
        .expect("run");
    let user = r.iter().find(|r| r.stage == "user").expect("user ran");
    assert_eq!(user.status, StageStatus::Ran);
    assert_eq!(user.summary, serde_json::json!(true));
    // Nothing changed: both up to date.
    let r = pair(false)
        .run(&ws, Some("user"), false, &NoProgress)
        .expect("run");
    assert!(r.iter().all(|r| r.status == StageStatus::UpToDate));
}
