//! Shared helpers for the integration tests: where `../shared`, the specs and the built binaries are.
use std::path::{Path, PathBuf};

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
    let msg = format!("SKIP: {what} needs ../shared beside the checkout (the peer policy and models); it is not there");
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
