//! Issue 30: a FIFO named as a world was taken for a preset name ("unknown world"), or, with
//! `.toml`, blocked `open()`. Any existing path is read as a scenario file, and a FIFO is refused
//! as such, at once.
use g1_sim::world::World;

#[test]
fn a_fifo_as_a_world_is_refused_as_a_fifo() {
    let dir = std::env::temp_dir().join(format!("g1sim-world-fifo-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    for name in ["world.fifo", "world.toml"] {
        let fifo = dir.join(name);
        let c = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
        // SAFETY: a valid NUL-terminated path; mkfifo only creates a file system node.
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
        let Err(e) = World::resolve(fifo.to_str().unwrap()) else {
            panic!("{name}: accepted")
        };
        let text = format!(
            "{e}: {}",
            std::error::Error::source(&e).map_or(String::new(), |s| s.to_string())
        );
        assert!(
            text.contains("a FIFO (named pipe), not a regular file"),
            "{name}: {text}"
        );
    }
    assert!(World::resolve("stairs-up").is_ok());
    std::fs::remove_dir_all(&dir).unwrap();
}
