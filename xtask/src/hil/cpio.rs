//! A minimal writer of the `newc` cpio format, the one the Linux kernel unpacks as an initramfs
//! (Documentation/driver-api/early-userspace/buffer-format.rst). Written here so the QEMU guest's
//! initramfs needs no `cpio` tool; entries are written in the order given, with fixed inode numbers
//! and times, so the same inputs give the same bytes.

/// One entry of the archive.
pub enum Entry<'a> {
    Dir(&'a str),
    /// Path, permission bits, contents.
    File(&'a str, u32, &'a [u8]),
    /// Path, permission bits, major, minor.
    CharDev(&'a str, u32, u32, u32),
}

const S_IFDIR: u32 = 0o040000;
const S_IFREG: u32 = 0o100000;
const S_IFCHR: u32 = 0o020000;

fn pad4(out: &mut Vec<u8>) {
    while !out.len().is_multiple_of(4) {
        out.push(0);
    }
}

fn header(out: &mut Vec<u8>, ino: u32, mode: u32, size: usize, rdev: (u32, u32), name: &str) {
    let fields = [
        ino,
        mode,
        0, // uid
        0, // gid
        if mode & S_IFDIR != 0 { 2 } else { 1 },
        0, // mtime
        size as u32,
        0, // devmajor
        0, // devminor
        rdev.0,
        rdev.1,
        name.len() as u32 + 1,
        0, // check
    ];
    out.extend_from_slice(b"070701");
    for f in fields {
        out.extend_from_slice(format!("{f:08X}").as_bytes());
    }
    out.extend_from_slice(name.as_bytes());
    out.push(0);
    pad4(out);
}

/// The archive: every entry, then the `TRAILER!!!` record. Paths are relative (`bin/busybox`).
pub fn archive(entries: &[Entry]) -> Vec<u8> {
    let mut out = Vec::new();
    for (i, e) in entries.iter().enumerate() {
        let ino = i as u32 + 1;
        match *e {
            Entry::Dir(p) => header(&mut out, ino, S_IFDIR | 0o755, 0, (0, 0), p),
            Entry::File(p, perm, data) => {
                header(&mut out, ino, S_IFREG | perm, data.len(), (0, 0), p);
                out.extend_from_slice(data);
                pad4(&mut out);
            }
            Entry::CharDev(p, perm, major, minor) => header(&mut out, ino, S_IFCHR | perm, 0, (major, minor), p),
        }
    }
    header(&mut out, 0, 0, 0, (0, 0), "TRAILER!!!");
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Name, mode, data, (rdev major, minor).
    type Parsed = (String, u32, Vec<u8>, (u32, u32));

    /// Parses the archive back (a reader written from the format description, not from the writer).
    fn parse(mut b: &[u8]) -> Vec<Parsed> {
        let mut out = Vec::new();
        let total = b.len();
        loop {
            assert_eq!(&b[..6], b"070701");
            let field =
                |i: usize| u32::from_str_radix(std::str::from_utf8(&b[6 + 8 * i..14 + 8 * i]).unwrap(), 16).unwrap();
            let (mode, size, rmaj, rmin, namesize) =
                (field(1), field(6) as usize, field(9), field(10), field(11) as usize);
            let name = std::str::from_utf8(&b[110..110 + namesize - 1]).unwrap().to_string();
            assert_eq!(b[110 + namesize - 1], 0, "name is NUL-terminated");
            let data_at = (110 + namesize).div_ceil(4) * 4;
            let data = b[data_at..data_at + size].to_vec();
            let next = (data_at + size).div_ceil(4) * 4;
            assert_eq!((total - b.len() + data_at) % 4, 0, "data is 4-byte aligned");
            if name == "TRAILER!!!" {
                assert_eq!(next, b.len(), "nothing after the trailer");
                return out;
            }
            out.push((name, mode, data, (rmaj, rmin)));
            b = &b[next..];
        }
    }

    #[test]
    fn round_trip_with_odd_lengths() {
        let a = archive(&[
            Entry::Dir("dev"),
            Entry::CharDev("dev/console", 0o600, 5, 1),
            Entry::File("init", 0o755, b"#!/bin/sh\n"),
            Entry::File("lib/modules/a.ko", 0o644, b"x"),
            Entry::File("e", 0o644, b""),
        ]);
        let got = parse(&a);
        assert_eq!(got.len(), 5);
        assert_eq!(got[0].0, "dev");
        assert_eq!(got[0].1, 0o040755);
        assert_eq!((got[1].1, got[1].3), (0o020600, (5, 1)));
        assert_eq!(
            (got[2].0.as_str(), got[2].1, got[2].2.as_slice()),
            ("init", 0o100755, &b"#!/bin/sh\n"[..])
        );
        assert_eq!(got[3].2, b"x");
        assert!(got[4].2.is_empty());
    }
}
