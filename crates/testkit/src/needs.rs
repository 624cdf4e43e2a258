//! What the real-data and tool-dependent tests need (a data set under `../shared/datasets`, a
//! shared evaluation script, `ffmpeg`, `python3` with numpy), probed by a crate's build script and
//! checked again by the test itself.
//!
//! A test that needs something is marked, for example,
//! `#[cfg_attr(not(has_herzjesu), ignore = "needs ../shared/datasets/herzjesu-P8 (missing)")]`, so
//! that a missing data set shows as *ignored*, with its reason, in the test summary instead of as a
//! silent pass. The crate's `build.rs` includes this file (`#[path]`: it uses only `std`) and
//! calls [`emit`], which sets the `has_*` cfg for each need that is present. With the environment
//! variable `CI` set, every cfg is set: nothing is ignored, and the test fails through
//! [`dataset`], [`ffmpeg`] or [`numpy`] with a message naming what is missing.
//!
//! `HANDHELD_DATASETS` (read at build time) points the tests at another data set folder; the
//! shared scripts are then looked for in `tools/` beside it, as `handheld bench` does.

#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

/// The environment variable that overrides the data set folder (at build time).
pub const DATASETS_ENV: &str = "HANDHELD_DATASETS";

/// The environment variable, set by the build script, that the tests read with `env!`.
pub const DATASETS_DIR_ENV: &str = "HANDHELD_DATASETS_DIR";

/// One thing a test needs from outside the repository.
#[derive(Debug, Clone, Copy)]
pub enum Need {
    /// `<datasets>/<name>` is a folder.
    Dataset(&'static str),
    /// `<datasets>/../tools/<name>` is a file (e.g. `eval_sfm.py`).
    Tool(&'static str),
    /// `ffmpeg -version` runs.
    Ffmpeg,
    /// `python3 -c "import numpy"` succeeds.
    Numpy,
    /// `chromium --version` runs (the report's browser test).
    Chromium,
    /// This CPU has AVX-512 VNNI. Hardware cannot be installed, so this need is never forced on
    /// under `CI`: its tests stay ignored (and say so) on a machine without it.
    Vnni,
}

/// The data set folder: `$HANDHELD_DATASETS` if set, else `../shared/datasets` beside the
/// repository (`manifest_dir` is a crate's folder, `<repo>/crates/<crate>`).
pub fn datasets_dir(manifest_dir: &Path) -> PathBuf {
    match std::env::var_os(DATASETS_ENV) {
        Some(p) if !p.is_empty() => PathBuf::from(p),
        _ => manifest_dir.join("../../../shared/datasets"),
    }
}

/// Why `need` is not met (`None`: it is), with what to do about it.
pub fn missing(need: Need, datasets: &Path) -> Option<String> {
    match need {
        Need::Dataset(name) => {
            let p = datasets.join(name);
            (!p.is_dir()).then(|| {
                format!(
                    "needs the data set {} (missing): put the shared folder at ../shared beside \
                     the repository, or set {DATASETS_ENV} to a folder holding {name}",
                    p.display()
                )
            })
        }
        Need::Tool(name) => {
            let p = tools_dir(datasets).join(name);
            (!p.is_file()).then(|| {
                format!(
                    "needs the shared script {} (missing): it comes with ../shared/tools",
                    p.display()
                )
            })
        }
        Need::Ffmpeg => (!runs("ffmpeg", &["-version"])).then(|| {
            "needs ffmpeg on PATH (missing): apt-get install ffmpeg (.ci/run does)".to_string()
        }),
        Need::Numpy => (!runs("python3", &["-c", "import numpy"])).then(|| {
            "needs python3 with numpy (missing): apt-get install python3 python3-numpy \
             (.ci/run does)"
                .to_string()
        }),
        Need::Chromium => (!runs(&chromium_program(), &["--version"])).then(|| {
            "needs chromium on PATH or $HANDHELD_CHROMIUM (missing): apt-get install chromium \
             (.ci/run does)"
                .to_string()
        }),
        Need::Vnni => (!have_vnni()).then(|| "needs a CPU with AVX-512 VNNI".to_string()),
    }
}

/// `$HANDHELD_CHROMIUM` if set (the report's browser test honours it), else `chromium`.
pub fn chromium_program() -> String {
    std::env::var("HANDHELD_CHROMIUM")
        .ok()
        .filter(|p| !p.is_empty())
        .unwrap_or_else(|| "chromium".to_string())
}

/// `<datasets>/../tools`: where the shared evaluation scripts lie.
pub fn tools_dir(datasets: &Path) -> PathBuf {
    datasets.join("../tools")
}

fn runs(program: &str, args: &[&str]) -> bool {
    Command::new(program)
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

fn have_vnni() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx512f")
            && std::arch::is_x86_feature_detected!("avx512bw")
            && std::arch::is_x86_feature_detected!("avx512vnni")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// For a build script: declares every `(cfg, need)` pair, sets the cfg of each need that is met
/// (all of them, except [`Need::Vnni`], when `CI` is set), passes the data set folder to the tests
/// as `HANDHELD_DATASETS_DIR`, and asks to be run again when `CI` or `HANDHELD_DATASETS` changes,
/// or when a data set, script or program appears or goes, and, while a program is missing, when
/// `PATH` changes. (Not on every change of `PATH`: each run of this script rebuilds the crate and
/// everything above it. A numpy installed later into the same python3 is seen after
/// `touch crates/<crate>/build.rs`.)
pub fn emit(needs: &[(&str, Need)]) {
    let manifest = PathBuf::from(std::env::var_os("CARGO_MANIFEST_DIR").unwrap_or_default());
    let datasets = datasets_dir(&manifest);
    let ci = std::env::var_os("CI").is_some_and(|v| !v.is_empty());
    println!("cargo:rerun-if-env-changed=CI");
    println!("cargo:rerun-if-env-changed={DATASETS_ENV}");
    println!("cargo:rerun-if-env-changed=HANDHELD_CHROMIUM");
    println!("cargo:rustc-env={DATASETS_DIR_ENV}={}", datasets.display());
    let mut watched = Vec::new();
    for &(cfg, need) in needs {
        println!("cargo:rustc-check-cfg=cfg({cfg})");
        let why = missing(need, &datasets);
        let forced = ci && !matches!(need, Need::Vnni);
        if why.is_none() || forced {
            println!("cargo:rustc-cfg={cfg}");
        }
        // While a program is missing, a change of `PATH` may bring it (or numpy's python3).
        if why.is_some() && matches!(need, Need::Ffmpeg | Need::Numpy | Need::Chromium) {
            println!("cargo:rerun-if-env-changed=PATH");
        }
        for p in watch_paths(need, &datasets, why.is_some()) {
            if !watched.contains(&p) {
                println!("cargo:rerun-if-changed={}", p.display());
                watched.push(p);
            }
        }
    }
}

/// What to watch so that the build script runs again when `need` changes: the data set, script
/// or program itself, or, while it is missing, the folder that would hold it (its appearance
/// changes that folder; cargo scans a watched folder's files, so nothing higher up is watched);
/// for a missing program, the folders on `PATH`. numpy is watched through `python3`.
fn watch_paths(need: Need, datasets: &Path, is_missing: bool) -> Vec<PathBuf> {
    let parent = |p: PathBuf| -> Vec<PathBuf> {
        p.parent()
            .filter(|q| q.is_dir())
            .map(|q| vec![q.to_path_buf()])
            .unwrap_or_default()
    };
    let path_dirs = || -> Vec<PathBuf> {
        std::env::var_os("PATH")
            .map(|p| {
                std::env::split_paths(&p)
                    .filter(|d| d.is_absolute() && d.is_dir())
                    .collect()
            })
            .unwrap_or_default()
    };
    let program = |name: &str| -> Vec<PathBuf> {
        match path_dirs()
            .into_iter()
            .map(|d| d.join(name))
            .find(|p| p.is_file())
        {
            Some(p) if !is_missing => vec![p],
            _ => path_dirs(),
        }
    };
    match need {
        Need::Dataset(name) if !is_missing => vec![datasets.join(name)],
        Need::Dataset(name) => parent(datasets.join(name)),
        Need::Tool(name) if !is_missing => vec![tools_dir(datasets).join(name)],
        Need::Tool(name) => parent(tools_dir(datasets).join(name)),
        Need::Ffmpeg => program("ffmpeg"),
        Need::Chromium => program(&chromium_program()),
        Need::Numpy => program("python3"),
        Need::Vnni => Vec::new(),
    }
}

/// For a test: `<datasets>/<name>`, or a panic naming the missing folder and what to do.
/// `datasets` is `env!("HANDHELD_DATASETS_DIR")`.
#[track_caller]
pub fn dataset(datasets: &str, name: &'static str) -> PathBuf {
    let root = PathBuf::from(datasets);
    if let Some(why) = missing(Need::Dataset(name), &root) {
        panic!("{why}");
    }
    root.join(name)
}

/// For a test: the shared script `<datasets>/../tools/<name>`, or a panic naming it.
#[track_caller]
pub fn tool(datasets: &str, name: &'static str) -> PathBuf {
    let root = PathBuf::from(datasets);
    if let Some(why) = missing(Need::Tool(name), &root) {
        panic!("{why}");
    }
    tools_dir(&root).join(name)
}

/// For a test: panics, saying what to install, unless `ffmpeg` runs.
#[track_caller]
pub fn ffmpeg() {
    if let Some(why) = missing(Need::Ffmpeg, Path::new("")) {
        panic!("{why}");
    }
}

/// For a test: panics, saying what to install, unless `chromium` runs.
#[track_caller]
pub fn chromium() {
    if let Some(why) = missing(Need::Chromium, Path::new("")) {
        panic!("{why}");
    }
}

/// For a test: panics, saying what to install, unless `python3` imports numpy.
#[track_caller]
pub fn numpy() {
    if let Some(why) = missing(Need::Numpy, Path::new("")) {
        panic!("{why}");
    }
}
