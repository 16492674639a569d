//! A directory of compiled models (`$G1_SIM_MODEL_CACHE`), so a process that loads the same model
//! again skips MuJoCo's compile (mesh parsing, convex hulls, inertias: ~1 s here, 80–90 s under
//! QEMU's software emulation, where the CAN HIL starts one simulator per fault run).
//!
//! An entry is MuJoCo's own binary model (MJB, `mj_saveModel`) of the edited, compiled model, plus
//! the slot torque clamps the edits produced, behind a SHA-256 of both. MJB stores every array of
//! `mjModel`, so a model loaded from it steps bit for bit like the compiled one (tested). The entry's
//! name is a SHA-256 of everything the compile depends on, by content: every file of the model's
//! directory tree, the running executable (any rebuild of the edits invalidates it), the simulator
//! config, the world and the terrain pool. Sizes and modification times are not enough: `cp -p` and
//! `rsync -t` make an edited model with the old size and time. A missing, unreadable, damaged or
//! not-regular entry (a FIFO, a device) is said, compiled again and rewritten; a cache that cannot be
//! written is reported and ignored, and leaves no temporary file behind (nor do dead processes').
use std::path::{Path, PathBuf};

use hal::NUM_MOTORS;
use mujoco_rs::prelude::MjModel;
use sha2::{Digest, Sha256};

/// Environment variable naming the cache directory (unset or empty: no cache).
pub const ENV: &str = "G1_SIM_MODEL_CACHE";

const MAGIC: &[u8; 16] = b"g1-sim model v2\n";
const CHECKSUM_BYTES: usize = 32;
/// Far above any G1 model's MJB (80 MB with meshes).
const MAX_ENTRY_BYTES: u64 = 2 << 30;
const LIMITS_BYTES: usize = NUM_MOTORS * 17;

pub type Limits = [Option<(f64, f64)>; NUM_MOTORS];

/// The cache directory from [`ENV`], if set.
pub fn dir_from_env() -> Option<PathBuf> {
    std::env::var_os(ENV).filter(|d| !d.is_empty()).map(PathBuf::from)
}

/// Hashes `path`'s name and, for a regular file, its content (anything else by its kind: a FIFO
/// in the model's tree must not hang the hash).
fn stamp(h: &mut Sha256, path: &Path) {
    let name = path.as_os_str().as_encoded_bytes();
    h.update((name.len() as u64).to_le_bytes());
    h.update(name);
    let regular = std::fs::metadata(path).is_ok_and(|m| m.is_file());
    let content = if regular { std::fs::File::open(path).ok() } else { None };
    match content {
        Some(mut f) => {
            let mut w = LengthPrefixed(h, 0);
            if std::io::copy(&mut f, &mut w).is_err() {
                w.0.update(b"unreadable");
            }
        }
        None => h.update(if regular {
            &b"unreadable"[..]
        } else {
            &b"not a regular file"[..]
        }),
    }
}

/// Hashes what is written, then its length (so concatenated files cannot collide).
struct LengthPrefixed<'a>(&'a mut Sha256, u64);

impl std::io::Write for LengthPrefixed<'_> {
    fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
        self.0.update(b);
        self.1 += b.len() as u64;
        Ok(b.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

impl Drop for LengthPrefixed<'_> {
    fn drop(&mut self) {
        self.0.update(self.1.to_le_bytes());
    }
}

/// Every file under `dir` (depth-limited, sorted), stamped.
fn stamp_tree(h: &mut Sha256, dir: &Path, depth: u32) {
    let Ok(rd) = std::fs::read_dir(dir) else {
        h.update(b"unreadable dir");
        return;
    };
    let mut entries: Vec<PathBuf> = rd.filter_map(|e| e.ok().map(|e| e.path())).collect();
    entries.sort();
    for p in entries {
        if p.is_dir() {
            if depth > 0 {
                stamp_tree(h, &p, depth - 1);
            }
        } else {
            stamp(h, &p);
        }
    }
}

/// The entry file for these inputs. `inputs` is everything else the compile depends on, formatted.
pub fn entry_path(dir: &Path, model_file: &Path, inputs: &str) -> PathBuf {
    let mut h = Sha256::new();
    h.update(MAGIC);
    stamp(&mut h, model_file);
    if let Some(parent) = model_file.parent() {
        stamp_tree(&mut h, parent, 3);
    }
    match std::env::current_exe() {
        Ok(exe) => stamp(&mut h, &exe),
        Err(_) => h.update(b"no exe"),
    }
    h.update(inputs.as_bytes());
    let digest = h.finalize();
    let name: String = digest[..16].iter().map(|b| format!("{b:02x}")).collect();
    dir.join(format!("{name}.g1mjb"))
}

/// Reads an entry: `None` if absent, or `Err(reason)` if it exists but cannot be used.
pub fn read(path: &Path) -> Option<Result<(MjModel, Limits), String>> {
    let bytes = match input_file::read_capped(path, MAX_ENTRY_BYTES) {
        Ok(b) => b,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return None,
        Err(e) => return Some(Err(format!("reading {}: {e}", path.display()))),
    };
    Some(decode(&bytes).map_err(|e| format!("{}: {e}", path.display())))
}

fn decode(bytes: &[u8]) -> Result<(MjModel, Limits), String> {
    let head = MAGIC.len() + CHECKSUM_BYTES;
    if bytes.len() < head + LIMITS_BYTES || &bytes[..MAGIC.len()] != MAGIC {
        return Err("not a g1-sim model cache entry".into());
    }
    if Sha256::digest(&bytes[head..])[..] != bytes[MAGIC.len()..head] {
        return Err("its checksum does not match its content (damaged)".into());
    }
    let mut limits = [None; NUM_MOTORS];
    let mut at = head;
    for lim in &mut limits {
        let f = |i: usize| f64::from_le_bytes(bytes[i..i + 8].try_into().expect("8 bytes"));
        if bytes[at] == 1 {
            *lim = Some((f(at + 1), f(at + 9)));
        }
        at += 17;
    }
    let model = MjModel::from_buffer(&bytes[at..]).map_err(|e| format!("MuJoCo could not load its MJB: {e}"))?;
    Ok((model, limits))
}

/// Writes an entry atomically (temporary file, then rename).
pub fn write(path: &Path, model: &MjModel, limits: &Limits) -> Result<(), String> {
    let mut bytes = Vec::with_capacity(MAGIC.len() + CHECKSUM_BYTES + LIMITS_BYTES + model.size());
    bytes.extend_from_slice(MAGIC);
    bytes.extend_from_slice(&[0; CHECKSUM_BYTES]);
    for lim in limits {
        let (flag, (lo, hi)) = match lim {
            Some(l) => (1u8, *l),
            None => (0u8, (0.0, 0.0)),
        };
        bytes.push(flag);
        bytes.extend_from_slice(&lo.to_le_bytes());
        bytes.extend_from_slice(&hi.to_le_bytes());
    }
    let at = bytes.len();
    bytes.resize(at + model.size(), 0);
    model
        .save_to_buffer(&mut bytes[at..])
        .map_err(|e| format!("serialising the model: {e}"))?;
    let head = MAGIC.len() + CHECKSUM_BYTES;
    let sum = Sha256::digest(&bytes[head..]);
    bytes[MAGIC.len()..head].copy_from_slice(&sum);
    if let Some(d) = path.parent() {
        std::fs::create_dir_all(d).map_err(|e| format!("creating {}: {e}", d.display()))?;
        remove_dead_temporaries(d);
    }
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(format!(".{TMP_PREFIX}{}", std::process::id()));
    let tmp = PathBuf::from(tmp);
    let written = std::fs::write(&tmp, &bytes)
        .map_err(|e| format!("writing {}: {e}", tmp.display()))
        .and_then(|()| {
            std::fs::rename(&tmp, path).map_err(|e| format!("renaming {} to {}: {e}", tmp.display(), path.display()))
        });
    if written.is_err() {
        // A full disk must not keep an 80 MB half-entry per run.
        let _ = std::fs::remove_file(&tmp);
    }
    written
}

/// A temporary entry is `<entry>.tmp<pid>`.
const TMP_PREFIX: &str = "tmp";

/// Removes the temporary entries of processes that no longer run (killed mid-write).
fn remove_dead_temporaries(dir: &Path) {
    let Ok(rd) = std::fs::read_dir(dir) else { return };
    for p in rd.filter_map(|e| e.ok().map(|e| e.path())) {
        let pid = p
            .extension()
            .and_then(|e| e.to_str())
            .and_then(|e| e.strip_prefix(TMP_PREFIX))
            .and_then(|n| n.parse::<u32>().ok());
        let is_entry = p
            .file_stem()
            .is_some_and(|s| Path::new(s).extension().is_some_and(|e| e == "g1mjb"));
        if let (Some(pid), true) = (pid, is_entry) {
            if !Path::new(&format!("/proc/{pid}")).exists() {
                let _ = std::fs::remove_file(&p);
            }
        }
    }
}
