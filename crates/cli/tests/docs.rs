//! The documentation's commands still parse, and the README stays a front door.
//!
//! Every `handheld …` command shown in a fenced code block of `README.md`, `ARCHITECTURE.md` or
//! `docs/*.md` is run through the built binary with `--help` appended. clap parses every argument
//! before `--help` (an unknown subcommand, an unknown flag or a value its parser rejects fails with
//! exit 2) and then prints the help instead of running anything, so missing input files do not
//! matter. A command whose subcommand or flag no longer exists fails this test, naming the file
//! and line where it is shown.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

/// The README's size limit in bytes: it is the front door, the detail lives in `docs/`.
const README_MAX_BYTES: usize = 12 * 1024;
/// The longest line the README may have, in characters.
const README_MAX_LINE: usize = 200;

fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// The Markdown files whose commands are checked.
fn documents() -> Vec<PathBuf> {
    let root = repo_root();
    let mut files = vec![root.join("README.md"), root.join("ARCHITECTURE.md")];
    let mut pages: Vec<PathBuf> = std::fs::read_dir(root.join("docs"))
        .expect("docs/ exists")
        .map(|e| e.expect("docs/ entry").path())
        .filter(|p| p.extension().is_some_and(|e| e == "md"))
        .collect();
    pages.sort();
    files.extend(pages);
    files
}

/// Splits a shell line into words: single and double quotes group, a backslash escapes the next
/// character, an unquoted `#` at a word's start begins a comment.
fn shell_words(line: &str) -> Vec<String> {
    let mut words = Vec::new();
    let mut word = String::new();
    let mut in_word = false;
    let mut quote: Option<char> = None;
    let mut chars = line.chars();
    while let Some(c) = chars.next() {
        match (quote, c) {
            (Some(q), c) if c == q => quote = None,
            (Some(_), c) => word.push(c),
            (None, '\'' | '"') => {
                quote = Some(c);
                in_word = true;
            }
            (None, '\\') => {
                if let Some(n) = chars.next() {
                    word.push(n);
                    in_word = true;
                }
            }
            (None, '#') if !in_word => break,
            (None, c) if c.is_whitespace() => {
                if in_word {
                    words.push(std::mem::take(&mut word));
                    in_word = false;
                }
            }
            (None, c) => {
                word.push(c);
                in_word = true;
            }
        }
    }
    if in_word {
        words.push(word);
    }
    words
}

/// A `handheld` command shown in a document: where, and its arguments.
#[derive(Debug)]
struct Shown {
    file: String,
    line: usize,
    text: String,
    args: Vec<String>,
}

/// The arguments after the program in `words`, if the words run `handheld`: the program itself
/// (`handheld`, `target/release/handheld`, …) or `cargo run … -p handheld -- ARGS`. The command
/// ends at a shell operator (`|`, `&&`, `;`, a redirection).
fn handheld_args(words: &[String]) -> Option<Vec<String>> {
    let is_cargo_run = words.len() > 1 && words[0] == "cargo" && words[1] == "run";
    let start = if is_cargo_run {
        let runs_handheld = words.windows(2).any(|w| w[0] == "-p" && w[1] == "handheld");
        let sep = words.iter().position(|w| w == "--")?;
        if !runs_handheld {
            return None;
        }
        sep + 1
    } else {
        // Skip `VAR=value` prefixes; the program must come next.
        let program = words.iter().position(|w| !is_env_assignment(w))?;
        let name = &words[program];
        if name != "handheld" && !name.ends_with("/handheld") {
            return None;
        }
        program + 1
    };
    let args = words[start..]
        .iter()
        .take_while(|w| {
            !matches!(
                w.as_str(),
                "|" | "&&" | "||" | ";" | ">" | "2>" | ">>" | "&"
            )
        })
        .cloned()
        .collect();
    Some(args)
}

fn is_env_assignment(w: &str) -> bool {
    match w.split_once('=') {
        Some((name, _)) => {
            !name.is_empty()
                && name
                    .chars()
                    .all(|c| c.is_ascii_uppercase() || c.is_ascii_digit() || c == '_')
        }
        None => false,
    }
}

/// Every `handheld` command in the fenced code blocks of `path`; a line ending in `\` continues.
fn shown_commands(path: &Path) -> Vec<Shown> {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let file = path
        .strip_prefix(repo_root())
        .unwrap_or(path)
        .display()
        .to_string();
    let mut shown = Vec::new();
    let mut in_block = false;
    let mut pending: Option<(usize, String)> = None;
    for (i, line) in text.lines().enumerate() {
        let trimmed = line.trim_start();
        if trimmed.starts_with("```") {
            in_block = !in_block;
            pending = None;
            continue;
        }
        if !in_block {
            continue;
        }
        let (start, mut joined) = pending.take().unwrap_or((i + 1, String::new()));
        joined.push_str(line.trim_end());
        if let Some(head) = joined.strip_suffix('\\') {
            pending = Some((start, format!("{head} ")));
            continue;
        }
        // A comment line (`# …`) shows no command.
        let words = shell_words(&joined);
        if let Some(args) = handheld_args(&words) {
            shown.push(Shown {
                file: file.clone(),
                line: start,
                text: joined.trim().to_string(),
                args,
            });
        }
    }
    shown
}

#[test]
fn shell_words_split_like_a_shell() {
    assert_eq!(
        shell_words(r#"handheld render ws --pose "my pose.json" -o v.png   # a comment"#),
        [
            "handheld",
            "render",
            "ws",
            "--pose",
            "my pose.json",
            "-o",
            "v.png"
        ]
    );
    let w = shell_words("QT_QPA_PLATFORM=offscreen target/release/handheld bench matching");
    assert_eq!(handheld_args(&w).unwrap(), ["bench", "matching"]);
    let w = shell_words("cargo run --release -p handheld -- demo --video");
    assert_eq!(handheld_args(&w).unwrap(), ["demo", "--video"]);
    let w = shell_words("cargo test -p handheld --test docs");
    assert!(handheld_args(&w).is_none());
    let w = shell_words("handheld --json report ws | jq .bytes");
    assert_eq!(handheld_args(&w).unwrap(), ["--json", "report", "ws"]);
}

#[test]
fn an_unknown_flag_before_help_is_rejected() {
    // The check below relies on clap parsing every argument before `--help`.
    let run = |args: &[&str]| {
        Command::new(env!("CARGO_BIN_EXE_handheld"))
            .args(args)
            .stdin(Stdio::null())
            .output()
            .expect("the handheld binary runs")
            .status
            .code()
    };
    assert_eq!(run(&["reconstruct", "in", "-o", "ws", "--help"]), Some(0));
    assert_eq!(
        run(&["reconstruct", "in", "-o", "ws", "--no-such-flag", "--help"]),
        Some(2)
    );
    assert_eq!(
        run(&[
            "reconstruct",
            "in",
            "-o",
            "ws",
            "--pairs",
            "nonsense",
            "--help"
        ]),
        Some(2)
    );
    assert_eq!(run(&["no-such-command", "--help"]), Some(2));
}

#[test]
fn every_documented_command_parses() {
    let mut shown = Vec::new();
    for doc in documents() {
        shown.extend(shown_commands(&doc));
    }
    assert!(
        shown.len() >= 20,
        "expected the docs to show at least 20 handheld commands, found {}",
        shown.len()
    );
    let mut failures = Vec::new();
    for s in &shown {
        let out = Command::new(env!("CARGO_BIN_EXE_handheld"))
            .args(&s.args)
            .arg("--help")
            .stdin(Stdio::null())
            .output()
            .expect("the handheld binary runs");
        if !out.status.success() {
            failures.push(format!(
                "{}:{}: `{}` → {}",
                s.file,
                s.line,
                s.text,
                String::from_utf8_lossy(&out.stderr)
                    .lines()
                    .next()
                    .unwrap_or("(no message)")
            ));
        }
    }
    assert!(
        failures.is_empty(),
        "documented commands that no longer parse:\n{}",
        failures.join("\n")
    );
}

#[test]
fn the_readme_stays_short() {
    let path = repo_root().join("README.md");
    let text = std::fs::read_to_string(&path).expect("README.md");
    assert!(
        text.len() < README_MAX_BYTES,
        "README.md is {} bytes; keep it under {README_MAX_BYTES} (move detail into docs/)",
        text.len()
    );
    for (i, line) in text.lines().enumerate() {
        let n = line.chars().count();
        assert!(
            n <= README_MAX_LINE,
            "README.md:{}: {n} characters; keep lines at most {README_MAX_LINE}",
            i + 1
        );
    }
}
