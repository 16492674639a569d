//! The compiled-model cache (`$G1_SIM_MODEL_CACHE`): a model loaded from it steps bit for bit like
//! a fresh compile, a changed input gets its own entry, and a damaged entry is compiled again.
// The simulator never runs on the robot: std's math is fine here (see clippy.toml).
#![allow(clippy::disallowed_methods)]
mod common;

use std::path::{Path, PathBuf};

use common::{have_12dof, require_deps};
use g1_sim::world::World;
use g1_sim::{ModelChoice, SimConfig, Simulator};

/// Holds the initial pose for 0.5 s (the robot settles: contacts and the solver act); returns
/// every qpos and qvel value's bits.
fn trace(sim: &mut Simulator) -> Vec<u64> {
    let cmd = sim.hold_initial_pose_command();
    sim.apply_command(&cmd).unwrap();
    let mut out = Vec::new();
    while sim.time() < 0.5 {
        sim.step_control_tick();
        let d = sim.data();
        out.extend(d.qpos().iter().chain(d.qvel().iter()).map(|v| v.to_bits()));
    }
    out
}

/// A fresh directory under the system's temp dir, removed when dropped.
struct TempDir(std::path::PathBuf);

impl TempDir {
    fn new(name: &str) -> Self {
        let p = std::env::temp_dir().join(format!("g1-sim-model-cache-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&p);
        std::fs::create_dir_all(&p).unwrap();
        Self(p)
    }
    fn path(&self) -> &Path {
        &self.0
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn entries(dir: &Path) -> Vec<std::path::PathBuf> {
    let mut v: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "g1mjb"))
        .collect();
    v.sort();
    v
}

fn check(name: &str, choice: ModelChoice, world: Option<&World>) {
    let dir = TempDir::new(name);
    let config = SimConfig::default();
    let mut fresh = Simulator::load_with_model_cache(choice.clone(), config, world, None).unwrap();
    assert!(fresh.model_cache_note().is_none());
    let want = trace(&mut fresh);

    let mut first = Simulator::load_with_model_cache(choice.clone(), config, world, Some(dir.path())).unwrap();
    let note = first.model_cache_note().unwrap().to_string();
    assert!(note.starts_with("model compiled and cached in "), "{note}");
    assert_eq!(entries(dir.path()).len(), 1);
    assert!(
        trace(&mut first) == want,
        "a compile that wrote the cache stepped differently"
    );

    let mut cached = Simulator::load_with_model_cache(choice.clone(), config, world, Some(dir.path())).unwrap();
    let note = cached.model_cache_note().unwrap().to_string();
    assert!(note.starts_with("model from cache "), "{note}");
    assert!(
        trace(&mut cached) == want,
        "the cached model stepped differently from a fresh compile"
    );

    // Another timestep is another entry, never the first one's model.
    let other = SimConfig {
        physics_dt: 0.001,
        control_dt: 0.002,
        ..config
    };
    let s = Simulator::load_with_model_cache(choice.clone(), other, world, Some(dir.path())).unwrap();
    assert!(s.model_cache_note().unwrap().starts_with("model compiled and cached"));
    assert_eq!(s.data().model().opt().timestep, 0.001);
    assert_eq!(entries(dir.path()).len(), 2);

    // A damaged entry is said, compiled again and rewritten; the model is still right.
    let first_entry = note.trim_start_matches("model from cache ").to_string();
    let mut bytes = std::fs::read(&first_entry).unwrap();
    bytes.truncate(bytes.len() / 2);
    std::fs::write(&first_entry, &bytes).unwrap();
    let mut again = Simulator::load_with_model_cache(choice, config, world, Some(dir.path())).unwrap();
    let note = again.model_cache_note().unwrap().to_string();
    assert!(
        note.contains("model cache entry unusable") && note.contains("model compiled and cached"),
        "{note}"
    );
    assert!(trace(&mut again) == want);
}

#[test]
fn a_cached_29dof_model_steps_bit_for_bit_like_a_fresh_compile() {
    require_deps();
    check("29dof", ModelChoice::G1_29Dof, None);
}

#[test]
fn a_cached_12dof_model_in_a_stair_world_steps_bit_for_bit_like_a_fresh_compile() {
    if !have_12dof("a_cached_12dof_model_in_a_stair_world_steps_bit_for_bit_like_a_fresh_compile") {
        return;
    }
    let world = World::resolve("stairs-up").unwrap();
    check("12dof", ModelChoice::G1_12Dof, Some(&world));
}

#[test]
fn an_unwritable_cache_is_reported_and_the_model_still_loads() {
    require_deps();
    let dir = TempDir::new("unwritable");
    let blocker = dir.path().join("not-a-dir");
    std::fs::write(&blocker, b"a file where the cache directory should be").unwrap();
    let sim =
        Simulator::load_with_model_cache(ModelChoice::G1_29Dof, SimConfig::default(), None, Some(&blocker)).unwrap();
    let note = sim.model_cache_note().unwrap();
    assert!(note.contains("the cache could not be written"), "{note}");
}

fn copy_tree(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let p = e.unwrap().path();
        let dest = to.join(p.file_name().unwrap());
        if p.is_dir() {
            copy_tree(&p, &dest);
        } else {
            std::fs::copy(&p, &dest).unwrap();
        }
    }
}

/// Nothing read from the cache is trusted unchecked: a model edited under the same size and
/// modification time (as `cp -p` or `rsync -t` make) gets its own entry; an entry with flipped bytes
/// or that is a FIFO is said and compiled again (no hang); dead processes' temporary entries go.
#[test]
fn the_cache_keys_on_content_and_checks_what_it_reads() {
    require_deps();
    let dir = TempDir::new("content");
    let cache = dir.path().join("cache");
    let model_dir = dir.path().join("g1");
    let xml_src = g1_sim::ModelChoice::G1_29Dof.path();
    copy_tree(xml_src.parent().unwrap(), &model_dir);
    let xml = model_dir.join(xml_src.file_name().unwrap());
    let choice = ModelChoice::Path(xml.clone());
    let config = SimConfig::default();
    let load = || Simulator::load_with_model_cache(choice.clone(), config, None, Some(&cache)).unwrap();

    let mut first = load();
    assert!(first
        .model_cache_note()
        .unwrap()
        .starts_with("model compiled and cached"));
    let old = trace(&mut first);

    // The pelvis 100 g heavier, the file's size and time unchanged.
    let text = std::fs::read_to_string(&xml).unwrap();
    let mtime = std::fs::metadata(&xml).unwrap().modified().unwrap();
    let edited = text.replacen("mass=\"3.813\"", "mass=\"3.913\"", 1);
    assert_eq!(edited.len(), text.len());
    assert_ne!(edited, text, "the model has no pelvis mass of 3.813 to edit");
    std::fs::write(&xml, &edited).unwrap();
    std::fs::File::options()
        .write(true)
        .open(&xml)
        .unwrap()
        .set_modified(mtime)
        .unwrap();
    let mut second = load();
    let note = second.model_cache_note().unwrap().to_string();
    assert!(
        note.starts_with("model compiled and cached"),
        "the edited model came from the old entry: {note}"
    );
    let new = trace(&mut second);
    assert!(new != old, "the edit changed nothing");
    let mut fresh = Simulator::load_with_model_cache(choice.clone(), config, None, None).unwrap();
    assert!(new == trace(&mut fresh));
    let entry = PathBuf::from(note.trim_start_matches("model compiled and cached in "));

    // 64 bytes flipped in the middle of the entry: same length, caught by the checksum.
    let mut bytes = std::fs::read(&entry).unwrap();
    let mid = bytes.len() / 2;
    bytes[mid..mid + 64].iter_mut().for_each(|b| *b ^= 0xa5);
    std::fs::write(&entry, &bytes).unwrap();
    let mut third = load();
    let note = third.model_cache_note().unwrap().to_string();
    assert!(note.contains("checksum") && note.contains("compiled again"), "{note}");
    assert!(trace(&mut third) == new);

    // An entry that is a FIFO: refused without blocking, replaced by a good entry.
    std::fs::remove_file(&entry).unwrap();
    let c = std::ffi::CString::new(entry.as_os_str().as_encoded_bytes()).unwrap();
    // SAFETY: a valid NUL-terminated path; mkfifo only creates a file.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
    let stale = PathBuf::from(format!("{}.tmp4194000", entry.display()));
    std::fs::write(&stale, b"half an entry of a killed process").unwrap();
    let mut fourth = load();
    let note = fourth.model_cache_note().unwrap().to_string();
    assert!(note.contains("FIFO") && note.contains("compiled again"), "{note}");
    assert!(trace(&mut fourth) == new);
    assert!(
        std::fs::metadata(&entry).unwrap().is_file(),
        "the FIFO was not replaced"
    );
    assert!(!stale.exists(), "a dead process's temporary entry was kept");
}
