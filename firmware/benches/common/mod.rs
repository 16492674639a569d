//! What the executor benches share: paths, loud notices, percentiles and running an ONNX Runtime
//! baseline script from the project's `.venv`.
use std::ffi::OsStr;
use std::path::{Path, PathBuf};
use std::process::Command;

pub fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// A notice that must not be missed in bench output (a skipped baseline).
pub fn loud(msg: &str) {
    eprintln!("\n************************************************************");
    eprintln!("{msg}");
    eprintln!("************************************************************\n");
}

/// The `p` quantile of an ascending slice (nearest rank).
pub fn percentile(sorted: &[f64], p: f64) -> f64 {
    sorted[((sorted.len() - 1) as f64 * p).round() as usize]
}

/// `.venv/bin/python` if it exists; otherwise says so loudly.
pub fn venv_python() -> Option<PathBuf> {
    let python = workspace_root().join(".venv/bin/python");
    if python.is_file() {
        Some(python)
    } else {
        loud(&format!(
            "NO ORT BASELINE: {} not found (scripts/install.sh creates it with onnx and onnxruntime)",
            python.display()
        ));
        None
    }
}

/// Runs `scripts/bench/<script>` with `args` under `python` from the workspace root and parses the
/// last line of its output as JSON; `None` (after saying why, loudly) if it cannot.
pub fn run_ort_script<I, S>(python: &Path, script: &str, args: I) -> Option<serde_json::Value>
where
    I: IntoIterator<Item = S>,
    S: AsRef<OsStr>,
{
    let root = workspace_root();
    let script = root.join("scripts/bench").join(script);
    let out = match Command::new(python).arg(&script).args(args).current_dir(&root).output() {
        Ok(o) => o,
        Err(e) => {
            loud(&format!("NO ORT BASELINE: cannot run {}: {e}", python.display()));
            return None;
        }
    };
    if !out.status.success() {
        loud(&format!(
            "NO ORT BASELINE: {} failed ({}) — is onnxruntime installed in .venv?\n{}",
            script.display(),
            out.status,
            String::from_utf8_lossy(&out.stderr)
        ));
        return None;
    }
    let stdout = String::from_utf8_lossy(&out.stdout);
    match stdout.lines().last().and_then(|l| serde_json::from_str(l).ok()) {
        Some(v) => Some(v),
        None => {
            loud(&format!("NO ORT BASELINE: unparsable output:\n{stdout}"));
            None
        }
    }
}
