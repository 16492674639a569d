//! Shared helpers for the integration tests: where `../shared`, the specs and the built binaries are.
// Integration tests never run on the robot: std's math is fine here (see clippy.toml).
#![allow(clippy::disallowed_methods)]
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};

pub mod soak;

/// Repository root.
pub fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("tests/ has a parent")
        .to_path_buf()
}

/// `../shared` beside the checkout (or `$G1_SHARED_DIR`), if present. When absent, tests that need
/// it call [`skip_or_fail`].
pub fn shared_dir() -> Option<PathBuf> {
    let p = std::env::var_os("G1_SHARED_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| repo_root().join("../shared"));
    p.join("peer_policy").is_dir().then_some(p)
}

/// Loud skip outside CI; a failure in CI (where `../shared` is always present).
pub fn skip_or_fail(what: &str) {
    skip_loudly_or_fail(&format!(
        "SKIP: {what} needs ../shared beside the checkout (the peer policy and models); it is not there"
    ));
}

/// Prints `msg` loudly and returns (the caller skips); under CI, where everything a test needs is
/// installed, panics with it instead.
pub fn skip_loudly_or_fail(msg: &str) {
    if std::env::var_os("CI").is_some() {
        panic!("{msg} — and CI must have it");
    }
    eprintln!("\n!!!!!!!! {msg} !!!!!!!!\n");
}

/// A binary built by `cargo build --release --bins` in this workspace's target directory.
pub fn built_bin(name: &str) -> PathBuf {
    let exe = std::env::current_exe().expect("current exe");
    // target/<profile>/deps/<test> → target/<profile>/<name>
    let dir = exe.parent().and_then(Path::parent).expect("target dir");
    let p = dir.join(name);
    assert!(
        p.is_file(),
        "{} not built: run `cargo build --release --workspace --bins` first",
        p.display()
    );
    p
}

/// A JSON file (a `g1fw` report) as a value.
pub fn read_json(path: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("reading {}: {e}", path.display()));
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// The peer policy's deploy spec.
pub fn peer_spec_path() -> PathBuf {
    repo_root().join("specs/peer/unitree_g1_lstm.toml")
}

/// Reads an f32/f64 tensor from a safetensors file as f64 values with its shape.
pub fn read_tensor(path: &Path, name: &str) -> (Vec<usize>, Vec<f64>) {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("reading {}: {e}", path.display()));
    let st = safetensors::SafeTensors::deserialize(&bytes).expect("valid safetensors");
    let t = st
        .tensor(name)
        .unwrap_or_else(|e| panic!("{name} in {}: {e}", path.display()));
    let data = t.data();
    let vals = match t.dtype() {
        safetensors::Dtype::F32 => data
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes(c.try_into().unwrap()) as f64)
            .collect(),
        safetensors::Dtype::F64 => data
            .chunks_exact(8)
            .map(|c| f64::from_le_bytes(c.try_into().unwrap()))
            .collect(),
        d => panic!("unsupported dtype {d:?}"),
    };
    (t.shape().to_vec(), vals)
}

/// The project's Python (created by scripts/install.sh), for independent readers and peers.
/// `None` (after a loud message; a failure under CI) when it is missing.
pub fn venv_python(what: &str) -> Option<PathBuf> {
    let p = repo_root().join(".venv/bin/python");
    if p.is_file() {
        return Some(p);
    }
    skip_loudly_or_fail(&format!(
        "SKIP: {what} needs the project's Python environment (.venv); run scripts/install.sh"
    ));
    None
}

/// Runs `tests/python/SCRIPT` with `py` (from [`venv_python`]) and parses what it prints as JSON;
/// a failing script fails the test with its stderr.
pub fn python_json<A: AsRef<std::ffi::OsStr>>(py: &Path, script: &str, args: &[A]) -> serde_json::Value {
    let out = std::process::Command::new(py)
        .arg(repo_root().join("tests/python").join(script))
        .args(args)
        .output()
        .unwrap_or_else(|e| panic!("cannot run {script}: {e}"));
    assert!(
        out.status.success(),
        "{script} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap_or_else(|e| panic!("{script} printed no JSON: {e}"))
}

/// A fresh scratch directory under the system temp dir, unique per test. Removed when the guard
/// drops, unless the test is failing: then its logs and reports stay for inspection (the path is
/// printed). Runs used to leave ~12 MB each in /tmp, on a disk CI shares.
pub fn scratch_dir(name: &str) -> ScratchDir {
    let d = std::env::temp_dir().join(format!("g1-it-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).expect("temp dir");
    ScratchDir(d)
}

/// See [`scratch_dir`]; derefs to its path.
pub struct ScratchDir(PathBuf);

impl std::ops::Deref for ScratchDir {
    type Target = Path;
    fn deref(&self) -> &Path {
        &self.0
    }
}

impl Drop for ScratchDir {
    fn drop(&mut self) {
        if std::thread::panicking() {
            eprintln!("test failed: its files are kept in {}", self.0.display());
        } else {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }
}

/// Runs the built `g1fw` with `args` from the repository root.
/// A `g1fw sim` that ran to its end: exit 0, or 3 when a safety trip latched (the report names it).
pub fn ran(out: &std::process::Output) -> bool {
    matches!(out.status.code(), Some(0 | 3))
}

pub fn g1fw(args: &[&str]) -> std::process::Output {
    std::process::Command::new(built_bin("g1fw"))
        .args(args)
        .current_dir(repo_root())
        .output()
        .expect("g1fw runs")
}

/// Scales the first f32 of the first tensor in a safetensors file by 1.001.
pub fn perturb_first_weight(bytes: &[u8]) -> Vec<u8> {
    let header_len = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    let header: serde_json::Value = serde_json::from_slice(&bytes[8..8 + header_len]).unwrap();
    let (_, first) = header
        .as_object()
        .unwrap()
        .iter()
        .find(|(k, v)| *k != "__metadata__" && v["dtype"] == "F32")
        .expect("an f32 tensor");
    let at = 8 + header_len + first["data_offsets"][0].as_u64().unwrap() as usize;
    let mut out = bytes.to_vec();
    let v = f32::from_le_bytes(out[at..at + 4].try_into().unwrap());
    let nv = if v == 0.0 { 1e-3 } else { v * 1.001 };
    out[at..at + 4].copy_from_slice(&nv.to_le_bytes());
    out
}

/// A network namespace with multicast on `lo`, deleted on drop.
pub struct Netns(String);

impl Netns {
    /// `None` when it cannot be made (not root, no `ip`): the caller says so loudly.
    pub fn new(tag: &str) -> Option<Netns> {
        let name = format!("{tag}-{}", std::process::id());
        let _ = Command::new("ip")
            .args(["netns", "del", &name])
            .stderr(Stdio::null())
            .status();
        let steps: [&[&str]; 4] = [
            &["netns", "add", &name],
            &["-n", &name, "link", "set", "lo", "up"],
            &["-n", &name, "link", "set", "lo", "multicast", "on"],
            &["-n", &name, "route", "add", "224.0.0.0/4", "dev", "lo"],
        ];
        for args in steps {
            let ok = Command::new("ip")
                .args(args)
                .stderr(Stdio::null())
                .status()
                .is_ok_and(|s| s.success());
            if !ok {
                let _ = Command::new("ip").args(["netns", "del", &name]).status();
                return None;
            }
        }
        Some(Netns(name))
    }

    /// The namespace's name (`ip netns exec NAME …`).
    pub fn name(&self) -> &str {
        &self.0
    }

    /// `program` run inside the namespace.
    pub fn command(&self, program: &Path) -> Command {
        let mut c = Command::new("ip");
        c.args(["netns", "exec", &self.0]).arg(program);
        c
    }
}

impl Netns {
    /// `g1fw run --dds lo,1 --spec SPEC ARGS… --report REPORT --log LOG` inside the namespace, from the
    /// repository root (specs name their files relative to it), to its end.
    pub fn g1fw_run_dds(&self, spec: &Path, args: &[&str], report: &Path, log: &Path) -> std::process::Output {
        self.command(&built_bin("g1fw"))
            .current_dir(repo_root())
            .args(["run", "--dds", "lo,1", "--spec"])
            .arg(spec)
            .args(args)
            .arg("--report")
            .arg(report)
            .arg("--log")
            .arg(log)
            .output()
            .expect("g1fw runs")
    }
}

impl Drop for Netns {
    fn drop(&mut self) {
        let _ = Command::new("ip").args(["netns", "del", &self.0]).status();
    }
}

/// Kills a child left behind by a failing test.
pub struct Reaped(pub Option<Child>);

impl Reaped {
    /// Waits for the child and parses the last line of its stdout that starts with `{`.
    pub fn wait_json(mut self, what: &str) -> serde_json::Value {
        let out = self.0.take().unwrap().wait_with_output().expect("wait");
        let text = String::from_utf8_lossy(&out.stdout);
        let line = text.lines().rev().find(|l| l.starts_with('{')).unwrap_or_else(|| {
            panic!(
                "{what} printed no JSON (status {}): stdout {text} stderr {}",
                out.status,
                String::from_utf8_lossy(&out.stderr)
            )
        });
        serde_json::from_str(line).unwrap_or_else(|e| panic!("{what}: {e}: {line}"))
    }
}

impl Drop for Reaped {
    fn drop(&mut self) {
        if let Some(c) = self.0.as_mut() {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

/// A report's `transitions` as (to, source, time s), in order.
pub fn transitions(report: &serde_json::Value) -> Vec<(String, String, f64)> {
    report["transitions"]
        .as_array()
        .unwrap_or_else(|| panic!("no transitions in {report}"))
        .iter()
        .map(|c| {
            (
                c["to"].as_str().unwrap().to_string(),
                c["source"].as_str().unwrap().to_string(),
                c["time_s"].as_f64().unwrap(),
            )
        })
        .collect()
}

/// The `/hal/low_state` ticks a log file holds, in file order, and how its scan ended if cut short
/// (a crash-truncated tail).
pub fn logged_ticks(path: &Path) -> (Vec<u64>, Option<String>) {
    let log = runlog::log::LogFile::open(path).expect("opens");
    let mut ticks = Vec::new();
    let end = log.scan(|topic, _, data| {
        if topic == runlog::log::channels::LOW_STATE {
            ticks.push(
                runlog::log::channels::decode_low_state_frame(data)
                    .expect("decodes")
                    .tick,
            );
        }
    });
    (ticks, end.truncated)
}

/// `g1fw replay LOG`: whether it succeeded and said the replay is identical, and what it printed.
pub fn replays_identical(log: &Path) -> (bool, String) {
    let out = g1fw(&["replay", log.to_str().unwrap()]);
    let text = String::from_utf8_lossy(&out.stdout).to_string() + &String::from_utf8_lossy(&out.stderr);
    (out.status.success() && text.contains("replay identical"), text)
}

/// `g1fw replay LOG` succeeds and says the replay is identical.
pub fn assert_replays_identical(log: &Path) {
    let (identical, text) = replays_identical(log);
    assert!(identical, "{text}");
}

/// `g1-sim --dds lo,1 --model g1-12dof --quiet --dds-idle-exit 1 EXTRA…` in `ns`, its output piped.
pub fn g1_sim_dds(ns: &Netns, extra: &[&str]) -> Reaped {
    Reaped(Some(
        ns.command(&built_bin("g1-sim"))
            .args([
                "--dds",
                "lo,1",
                "--model",
                "g1-12dof",
                "--quiet",
                "--dds-idle-exit",
                "1",
            ])
            .args(extra)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("g1-sim"),
    ))
}

#[cfg(test)]
mod scratch_tests {
    use super::scratch_dir;

    #[test]
    fn scratch_dirs_go_away_unless_the_test_fails() {
        let passed = scratch_dir("scratch-selftest-pass");
        std::fs::write(passed.join("log.mcap"), b"x").unwrap();
        let path = passed.to_path_buf();
        drop(passed);
        assert!(!path.exists(), "a passing test's scratch dir is removed");

        let failing = scratch_dir("scratch-selftest-fail");
        std::fs::write(failing.join("log.mcap"), b"x").unwrap();
        let kept = failing.to_path_buf();
        // The guard drops while the panic unwinds, as in a failing test.
        std::panic::catch_unwind(std::panic::AssertUnwindSafe(move || {
            let _guard = failing;
            panic!("a failing test");
        }))
        .unwrap_err();
        assert!(kept.join("log.mcap").exists(), "a failing test keeps its files");
        std::fs::remove_dir_all(kept).unwrap();
    }
}
