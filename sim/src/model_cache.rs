//! A directory of compiled models (`$G1_SIM_MODEL_CACHE`), so a process that loads the same model
//! again skips MuJoCo's compile (mesh parsing, convex hulls, inertias: ~1 s here, 80–90 s under
//! QEMU's software emulation, where the CAN HIL starts one simulator per fault run).
//!
//! An entry is MuJoCo's own binary model (MJB, `mj_saveModel`) of the edited, compiled model, plus
//! the slot torque clamps the edits produced. MJB stores every array of `mjModel`, so a model loaded
//! from it steps bit for bit like the compiled one (tested). The entry's name is a hash of everything
//! the compile depends on: the model file's directory tree (names, sizes, modification times), the
//! running executable (size, modification time: any rebuild of the edits invalidates it), the
//! simulator config, the world and the terrain pool. A missing, unreadable or corrupt entry is
//! compiled again and rewritten; a cache that cannot be written is reported and ignored.
use std::path::{Path, PathBuf};

use hal::NUM_MOTORS;
use mujoco_rs::prelude::MjModel;

/// Environment variable naming the cache directory (unset or empty: no cache).
pub const ENV: &str = "G1_SIM_MODEL_CACHE";

const MAGIC: &[u8; 16] = b"g1-sim model v1\n";
const LIMITS_BYTES: usize = NUM_MOTORS * 17;

pub type Limits = [Option<(f64, f64)>; NUM_MOTORS];

/// The cache directory from [`ENV`], if set.
pub fn dir_from_env() -> Option<PathBuf> {
    std::env::var_os(ENV).filter(|d| !d.is_empty()).map(PathBuf::from)
}

/// FNV-1a, 64 bit: a stable name for an entry (not a security boundary: the cache is the user's).
struct Fnv(u64);

impl Fnv {
    fn new() -> Self {
        Self(0xcbf2_9ce4_8422_2325)
    }
    fn bytes(&mut self, b: &[u8]) {
        // Length first, so concatenations of different fields cannot collide.
        for x in (b.len() as u64).to_le_bytes().iter().chain(b) {
            self.0 ^= u64::from(*x);
            self.0 = self.0.wrapping_mul(0x0100_0000_01b3);
        }
    }
}

fn stamp(h: &mut Fnv, path: &Path) {
    h.bytes(path.as_os_str().as_encoded_bytes());
    match std::fs::metadata(path) {
        Ok(m) => {
            h.bytes(&m.len().to_le_bytes());
            let t = m
                .modified()
                .ok()
                .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
                .map_or(0, |d| d.as_nanos());
            h.bytes(&t.to_le_bytes());
        }
        Err(_) => h.bytes(b"missing"),
    }
}

/// Every file under `dir` (depth-limited, sorted), stamped.
fn stamp_tree(h: &mut Fnv, dir: &Path, depth: u32) {
    let Ok(rd) = std::fs::read_dir(dir) else {
        h.bytes(b"unreadable dir");
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
    let mut h = Fnv::new();
    h.bytes(MAGIC);
    stamp(&mut h, model_file);
    if let Some(parent) = model_file.parent() {
        stamp_tree(&mut h, parent, 3);
    }
    match std::env::current_exe() {
        Ok(exe) => stamp(&mut h, &exe),
        Err(_) => h.bytes(b"no exe"),
    }
    h.bytes(inputs.as_bytes());
    dir.join(format!("{:016x}.g1mjb", h.0))
}

/// Reads an entry: `None` if absent, or `Err(reason)` if it exists but cannot be used.
pub fn read(path: &Path) -> Option<Result<(MjModel, Limits), String>> {
    let bytes = match std::fs::read(path) {
        Ok(b) => b,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return None,
        Err(e) => return Some(Err(format!("reading {}: {e}", path.display()))),
    };
    Some(decode(&bytes).map_err(|e| format!("{}: {e}", path.display())))
}

fn decode(bytes: &[u8]) -> Result<(MjModel, Limits), String> {
    if bytes.len() < MAGIC.len() + LIMITS_BYTES || &bytes[..MAGIC.len()] != MAGIC {
        return Err("not a g1-sim model cache entry".into());
    }
    let mut limits = [None; NUM_MOTORS];
    let mut at = MAGIC.len();
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
    let mut bytes = Vec::with_capacity(MAGIC.len() + LIMITS_BYTES + model.size());
    bytes.extend_from_slice(MAGIC);
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
    if let Some(d) = path.parent() {
        std::fs::create_dir_all(d).map_err(|e| format!("creating {}: {e}", d.display()))?;
    }
    let tmp = path.with_extension(format!("tmp{}", std::process::id()));
    std::fs::write(&tmp, &bytes).map_err(|e| format!("writing {}: {e}", tmp.display()))?;
    std::fs::rename(&tmp, path).map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        format!("renaming {} to {}: {e}", tmp.display(), path.display())
    })
}
