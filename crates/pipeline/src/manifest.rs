//! Resumption: one folder per stage, each finished stage marked by a `manifest.json` written last
//! (atomically). A stage is up to date when its manifest records the same input hash (its inputs'
//! fingerprints, its serialised options and the hashes of the stages it reads), the same Handheld
//! version and the same workspace format, and all its listed outputs exist. Re-running a stage first
//! deletes its manifest, so an interrupted run can never look finished.

use std::fs;
use std::path::{Path, PathBuf};
use std::time::{SystemTime, UNIX_EPOCH};

use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use handheld_io::atomic::write_bytes_atomic;
use handheld_io::{IoError, Result};

/// The version recorded in every manifest.
pub const HANDHELD_VERSION: &str = env!("CARGO_PKG_VERSION");

/// The workspace format recorded in every manifest. Format 1 (no field in the manifest) was written
/// by the CLI's own stage runner, whose fingerprints were built from strings; format 2 fingerprints
/// the serialised options. A stage written in another format is redone, with a message saying so.
pub const WORKSPACE_FORMAT: u32 = 2;

fn format_1() -> u32 {
    1
}

/// What a finished stage leaves behind.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StageManifest {
    pub stage: String,
    pub handheld_version: String,
    /// [`WORKSPACE_FORMAT`] of the run that wrote it.
    #[serde(default = "format_1")]
    pub workspace_format: u32,
    /// Hex SHA-256 of the stage's inputs and options (see [`Fingerprint`]).
    pub input_hash: String,
    pub options: serde_json::Value,
    /// Start time, seconds since the Unix epoch.
    pub started_unix_s: f64,
    /// Wall-clock duration of the stage.
    pub seconds: f64,
    /// Output files, relative to the stage folder.
    pub outputs: Vec<String>,
    /// The stage's typed summary, serialised (counts, errors) for reports.
    pub summary: serde_json::Value,
    /// Warnings the stage gave: a code, the message in plain language, what to do, details.
    #[serde(default)]
    pub warnings: Vec<crate::warning::Warning>,
}

/// Accumulates what a stage's result depends on.
#[derive(Clone)]
pub struct Fingerprint(Sha256);

impl Default for Fingerprint {
    fn default() -> Self {
        Self::new()
    }
}

impl Fingerprint {
    pub fn new() -> Self {
        Self(Sha256::new())
    }

    /// Adds a labelled string.
    pub fn add_str(&mut self, label: &str, value: &str) -> &mut Self {
        for part in [label.as_bytes(), value.as_bytes()] {
            self.0.update((part.len() as u64).to_le_bytes());
            self.0.update(part);
        }
        self
    }

    /// Adds any serialisable value (options structs) through its JSON form.
    pub fn add_json<T: Serialize>(&mut self, label: &str, value: &T) -> &mut Self {
        let text = serde_json::to_string(value).unwrap_or_default();
        self.add_str(label, &text)
    }

    /// Adds a file's identity: absolute path, size and modification time (content is not read, so
    /// fingerprinting a long video stays instant).
    pub fn add_file(&mut self, path: &Path) -> Result<&mut Self> {
        let meta = fs::metadata(path).map_err(|e| IoError::io(path, e))?;
        let mtime = meta
            .modified()
            .ok()
            .and_then(|t| t.duration_since(UNIX_EPOCH).ok())
            .map(|d| d.as_nanos())
            .unwrap_or(0);
        let abs = fs::canonicalize(path).unwrap_or_else(|_| path.to_path_buf());
        Ok(self.add_str(
            "file",
            &format!("{}|{}|{}", abs.display(), meta.len(), mtime),
        ))
    }

    pub fn hex(&self) -> String {
        self.0
            .clone()
            .finalize()
            .iter()
            .map(|b| format!("{b:02x}"))
            .collect()
    }
}

/// A workspace folder.
#[derive(Clone, Debug)]
pub struct Workspace {
    pub root: PathBuf,
}

impl Workspace {
    /// Opens (creating if needed) a workspace folder. Fails when the path exists and is not a folder.
    pub fn open(root: &Path) -> Result<Self> {
        if root.exists() && !root.is_dir() {
            return Err(IoError::Input {
                path: root.to_path_buf(),
                reason: "exists and is not a folder; choose another workspace path".into(),
            });
        }
        fs::create_dir_all(root).map_err(|e| IoError::io(root, e))?;
        Ok(Self {
            root: root.to_path_buf(),
        })
    }

    /// The folder of a stage (created on demand).
    pub fn stage_dir(&self, stage: &str) -> Result<PathBuf> {
        let dir = self.root.join(stage);
        fs::create_dir_all(&dir).map_err(|e| IoError::io(&dir, e))?;
        Ok(dir)
    }

    fn manifest_path(&self, stage: &str) -> PathBuf {
        self.root.join(stage).join("manifest.json")
    }

    /// The manifest of a finished stage, if any (an unreadable manifest counts as none).
    pub fn manifest(&self, stage: &str) -> Option<StageManifest> {
        let text = fs::read_to_string(self.manifest_path(stage)).ok()?;
        serde_json::from_str(&text).ok()
    }

    /// True when `stage` finished with this input hash, this Handheld version and this workspace
    /// format, and its outputs exist.
    pub fn is_up_to_date(&self, stage: &str, input_hash: &str) -> bool {
        let Some(m) = self.manifest(stage) else {
            return false;
        };
        let dir = self.root.join(stage);
        m.input_hash == input_hash
            && m.handheld_version == HANDHELD_VERSION
            && m.workspace_format == WORKSPACE_FORMAT
            && m.outputs.iter().all(|o| dir.join(o).exists())
    }

    /// Marks a stage as in progress: its manifest goes first (so an interrupted run never looks
    /// finished), then everything else in its folder, so a run that fails leaves no outputs of an
    /// earlier run that could pass for its own.
    pub fn begin(&self, stage: &str) -> Result<PathBuf> {
        let dir = self.stage_dir(stage)?;
        let m = self.manifest_path(stage);
        if m.exists() {
            fs::remove_file(&m).map_err(|e| IoError::io(&m, e))?;
        }
        fs::remove_dir_all(&dir).map_err(|e| IoError::io(&dir, e))?;
        self.stage_dir(stage)
    }

    /// Marks a stage as finished by writing its manifest, and records its time in `timings.json`.
    pub fn finish(&self, manifest: &StageManifest) -> Result<()> {
        let path = self.manifest_path(&manifest.stage);
        let text = serde_json::to_vec_pretty(manifest)
            .map_err(|e| IoError::format(&path, e.to_string()))?;
        write_bytes_atomic(&path, &text)?;
        self.record_timing(&manifest.stage, manifest.seconds)
    }

    /// Stage wall-clock times of the latest runs, `{stage: seconds}`.
    pub fn timings(&self) -> serde_json::Map<String, serde_json::Value> {
        let path = self.root.join("timings.json");
        fs::read_to_string(path)
            .ok()
            .and_then(|t| serde_json::from_str(&t).ok())
            .unwrap_or_default()
    }

    fn record_timing(&self, stage: &str, seconds: f64) -> Result<()> {
        let mut t = self.timings();
        t.insert(stage.to_string(), serde_json::json!(seconds));
        let path = self.root.join("timings.json");
        let text =
            serde_json::to_vec_pretty(&t).map_err(|e| IoError::format(&path, e.to_string()))?;
        write_bytes_atomic(&path, &text)
    }
}

/// Seconds since the Unix epoch.
pub fn now_unix_s() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_secs_f64())
        .unwrap_or(0.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn manifest(hash: &str) -> StageManifest {
        StageManifest {
            stage: "ingest".into(),
            handheld_version: HANDHELD_VERSION.into(),
            workspace_format: WORKSPACE_FORMAT,
            input_hash: hash.into(),
            options: serde_json::json!({}),
            started_unix_s: 0.0,
            seconds: 1.5,
            outputs: vec!["images.json".into()],
            summary: serde_json::json!({}),
            warnings: Vec::new(),
        }
    }

    #[test]
    fn stage_is_up_to_date_only_when_finished_with_same_hash() {
        let dir = tempfile::tempdir().unwrap();
        let ws = Workspace::open(&dir.path().join("ws")).unwrap();
        let mut fp = Fingerprint::new();
        fp.add_str("opt", "a");
        let h = fp.hex();
        assert!(!ws.is_up_to_date("ingest", &h));
        let stage = ws.begin("ingest").unwrap();
        fs::write(stage.join("images.json"), "[]").unwrap();
        assert!(!ws.is_up_to_date("ingest", &h), "no manifest yet");
        ws.finish(&manifest(&h)).unwrap();
        assert!(ws.is_up_to_date("ingest", &h));
        assert!(!ws.is_up_to_date("ingest", "other"));
        assert_eq!(ws.timings()["ingest"], serde_json::json!(1.5));
        fs::remove_file(stage.join("images.json")).unwrap();
        assert!(!ws.is_up_to_date("ingest", &h), "missing output");
        fs::write(stage.join("images.json"), "[]").unwrap();
        ws.begin("ingest").unwrap();
        assert!(ws.manifest("ingest").is_none());
        assert!(
            !stage.join("images.json").exists(),
            "a rerun leaves no outputs of the earlier run"
        );
    }

    #[test]
    fn a_manifest_of_the_first_format_is_not_up_to_date() {
        let dir = tempfile::tempdir().unwrap();
        let ws = Workspace::open(&dir.path().join("ws")).unwrap();
        let stage = ws.begin("ingest").unwrap();
        fs::write(stage.join("images.json"), "[]").unwrap();
        // As the CLI's runner wrote it: no `workspace_format`, no `warnings`.
        let old = r#"{"stage":"ingest","handheld_version":"VERSION","input_hash":"h","options":{},
            "started_unix_s":0.0,"seconds":1.0,"outputs":["images.json"],"summary":{}}"#
            .replace("VERSION", HANDHELD_VERSION);
        fs::write(stage.join("manifest.json"), old).unwrap();
        let m = ws.manifest("ingest").expect("old manifests still parse");
        assert_eq!(m.workspace_format, 1);
        assert!(!ws.is_up_to_date("ingest", "h"));
    }

    #[test]
    fn workspace_on_a_file_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let f = dir.path().join("file");
        fs::write(&f, "x").unwrap();
        let err = Workspace::open(&f).unwrap_err().to_string();
        assert!(err.contains("not a folder"), "{err}");
    }

    #[test]
    fn fingerprint_changes_with_content_labels() {
        let mut a = Fingerprint::new();
        a.add_str("x", "ab");
        let mut b = Fingerprint::new();
        b.add_str("xa", "b");
        assert_ne!(a.hex(), b.hex());
    }
}
