//! The one rule for every output of every binary: an output may not be an input, a file an input
//! names (a spec's weights), inside an output directory that is an input's, or another output.
//! Paths are compared resolved (symbolic links followed, `..` gone) and, for files that exist, by
//! device and inode, so a hard link to the spec is the spec. Every output is then written
//! atomically ([`write_atomically`]): a temporary file beside it, then a rename, so a full disk or a
//! kill leaves the old file or the new one, never half of one.
use std::ffi::OsString;
use std::io::Write;
use std::os::unix::fs::MetadataExt;
use std::path::{Path, PathBuf};

/// Whether an output is one file or a directory the program fills.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    File,
    Dir,
}

/// An output that would overwrite an input or another output.
#[derive(Debug, thiserror::Error)]
#[error("{flag} {} is also {other}: one would overwrite the other; give it another {what}", path.display())]
pub struct Clash {
    pub flag: String,
    pub path: PathBuf,
    pub other: String,
    what: &'static str,
}

/// A path as the file system resolves it, and the file's identity when it exists.
struct Resolved {
    path: PathBuf,
    inode: Option<(u64, u64)>,
}

fn resolve(p: &Path) -> Resolved {
    // An existing file resolves whole; a new one through its directory.
    let path = std::fs::canonicalize(p)
        .or_else(|_| {
            let dir = p
                .parent()
                .filter(|d| !d.as_os_str().is_empty())
                .unwrap_or(Path::new("."));
            let name = p.file_name().ok_or(std::io::ErrorKind::InvalidInput)?;
            std::fs::canonicalize(dir).map(|d| d.join(name))
        })
        .or_else(|_| std::path::absolute(p))
        .unwrap_or_else(|_| p.to_path_buf());
    let inode = std::fs::metadata(&path).ok().map(|m| (m.dev(), m.ino()));
    Resolved { path, inode }
}

impl Resolved {
    fn same(&self, other: &Resolved) -> bool {
        self.path == other.path || (self.inode.is_some() && self.inode == other.inode)
    }
}

/// Refuses `outputs` that would overwrite one another or one of `inputs` (each a flag or a
/// description, and its path). An input is also every file an input names: pass those too.
pub fn check(outputs: &[(&str, &Path, Kind)], inputs: &[(&str, &Path)]) -> Result<(), Clash> {
    let outs: Vec<(&str, Resolved, Kind)> = outputs.iter().map(|(f, p, k)| (*f, resolve(p), *k)).collect();
    let ins: Vec<(&str, Resolved)> = inputs.iter().map(|(f, p)| (*f, resolve(p))).collect();
    for (i, (flag, out, kind)) in outs.iter().enumerate() {
        let earlier = outs[..i].iter().map(|(f, r, _)| (*f, r));
        for (other, r) in earlier.chain(ins.iter().map(|(f, r)| (*f, r))) {
            let inside = *kind == Kind::Dir && r.path.starts_with(&out.path);
            if out.same(r) || inside {
                return Err(Clash {
                    flag: flag.to_string(),
                    path: out.path.clone(),
                    other: if inside && !out.same(r) {
                        format!("the directory of {other} {}", r.path.display())
                    } else {
                        other.to_string()
                    },
                    what: if *kind == Kind::Dir { "directory" } else { "file" },
                });
            }
        }
    }
    Ok(())
}

/// Whether `path` lies inside the directory `dir` (or is it), paths resolved as [`check`] resolves
/// them (links followed): e.g. a run directory inside a data directory would be read as data.
pub fn is_inside(path: &Path, dir: &Path) -> bool {
    let (p, d) = (resolve(path), resolve(dir));
    p.same(&d) || p.path.starts_with(&d.path)
}

/// [`check`] over the paths given: a flag whose value is `None` was not passed and takes no part.
pub fn check_given(outputs: &[(&str, Option<&Path>, Kind)], inputs: &[(&str, Option<&Path>)]) -> Result<(), Clash> {
    let outs: Vec<(&str, &Path, Kind)> = outputs.iter().filter_map(|(f, p, k)| p.map(|p| (*f, p, *k))).collect();
    let ins: Vec<(&str, &Path)> = inputs.iter().filter_map(|(f, p)| p.map(|p| (*f, p))).collect();
    check(&outs, &ins)
}

/// The temporary file [`write_atomically`] writes first: `path` + `.partial-<pid>`.
pub fn temporary(path: &Path) -> PathBuf {
    let mut t: OsString = path.as_os_str().to_owned();
    t.push(format!(".partial-{}", std::process::id()));
    PathBuf::from(t)
}

/// The temporary file [`write_through`] has a writer create: `path` with `.partial-<pid>` put
/// before its extension (`plot.png` → `plot.partial-<pid>.png`), for encoders that pick their
/// format by the extension.
pub fn temporary_keeping_extension(path: &Path) -> PathBuf {
    let stem = path.file_stem().unwrap_or_default().to_string_lossy();
    let name = match path.extension() {
        Some(ext) => format!("{stem}.partial-{}.{}", std::process::id(), ext.to_string_lossy()),
        None => format!("{stem}.partial-{}", std::process::id()),
    };
    path.with_file_name(name)
}

/// Has `write` create the file at [`temporary_keeping_extension`]`(path)`, then renames it over
/// `path`: a writer that fails or is killed half-way leaves `path` as it was. On error the
/// temporary file is removed.
pub fn write_through<E: From<std::io::Error>>(
    path: &Path,
    write: impl FnOnce(&Path) -> Result<(), E>,
) -> Result<(), E> {
    let tmp = temporary_keeping_extension(path);
    let done = write(&tmp).and_then(|()| std::fs::rename(&tmp, path).map_err(E::from));
    if done.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    done
}

/// Writes `bytes` to `path` through a temporary file beside it, synced, then renamed over it. On
/// any error the temporary file is removed and `path` is as it was.
pub fn write_atomically(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let tmp = temporary(path);
    let written = (|| {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if written.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    written
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("output-file-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn an_output_onto_an_input_a_link_a_hard_link_or_another_output_is_refused() {
        let d = scratch("clash");
        let spec = d.join("spec.toml");
        std::fs::write(&spec, "x").unwrap();
        let hard = d.join("hard.toml");
        std::fs::hard_link(&spec, &hard).unwrap();
        let soft = d.join("soft.toml");
        std::os::unix::fs::symlink(&spec, &soft).unwrap();
        let dotted = d.join("sub/../spec.toml");
        std::fs::create_dir_all(d.join("sub")).unwrap();
        for out in [&spec, &hard, &soft, &dotted] {
            let e = check(&[("--report", out, Kind::File)], &[("--spec", &spec)]).unwrap_err();
            assert!(e.to_string().contains("is also --spec"), "{e}");
        }
        let a = d.join("a.json");
        let e = check(&[("--report", &a, Kind::File), ("--log", &a, Kind::File)], &[]).unwrap_err();
        assert!(
            e.to_string().contains("--log") && e.to_string().contains("is also --report"),
            "{e}"
        );
        // A directory output that holds an input.
        let e = check(&[("--out", &d, Kind::Dir)], &[("--spec", &spec)]).unwrap_err();
        assert!(e.to_string().contains("the directory of --spec"), "{e}");
        // Distinct files pass, a new one included.
        check(&[("--report", &d.join("new.json"), Kind::File)], &[("--spec", &spec)]).unwrap();
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn a_writer_through_a_temporary_replaces_the_file_or_leaves_it() {
        let d = scratch("through");
        let f = d.join("plot.png");
        std::fs::write(&f, b"old").unwrap();
        let tmp = temporary_keeping_extension(&f);
        assert_eq!(tmp.extension().unwrap(), "png");
        let failed: std::io::Result<()> = write_through(&f, |t| {
            std::fs::write(t, b"half")?;
            Err(std::io::Error::other("the encoder failed"))
        });
        assert!(failed.is_err());
        assert_eq!(std::fs::read(&f).unwrap(), b"old", "a failed writer leaves the file");
        assert!(!tmp.exists(), "and no temporary");
        write_through(&f, |t| std::fs::write(t, b"new")).unwrap();
        assert_eq!(std::fs::read(&f).unwrap(), b"new");
        assert!(!tmp.exists());
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn inside_follows_links_and_dots() {
        let d = scratch("inside");
        let data = d.join("data");
        std::fs::create_dir_all(data.join("shard")).unwrap();
        std::fs::create_dir_all(d.join("other")).unwrap();
        std::os::unix::fs::symlink(&data, d.join("link")).unwrap();
        assert!(is_inside(&data.join("run"), &data));
        assert!(is_inside(&d.join("link/run"), &data), "through a link");
        assert!(is_inside(&d.join("other/../data/run"), &data), "through ..");
        assert!(is_inside(&data, &data));
        assert!(!is_inside(&d.join("run"), &data));
        assert!(!is_inside(&d.join("data-2"), &data), "a name that only starts alike");
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn a_failed_write_leaves_the_old_file_and_no_temporary() {
        let d = scratch("atomic");
        let f = d.join("report.json");
        write_atomically(&f, b"old").unwrap();
        write_atomically(&f, b"new").unwrap();
        assert_eq!(std::fs::read(&f).unwrap(), b"new");
        // Onto a directory: the rename fails, the temporary goes.
        let dir = d.join("a-dir");
        std::fs::create_dir(&dir).unwrap();
        std::fs::write(dir.join("keep"), b"k").unwrap();
        assert!(write_atomically(&dir, b"x").is_err());
        assert!(!temporary(&dir).exists());
        assert_eq!(std::fs::read(dir.join("keep")).unwrap(), b"k");
        std::fs::remove_dir_all(&d).unwrap();
    }
}
