//! Damaged logs (issue 22): random single-byte changes of a committed log are each named as damage
//! by the reader, replay stops at the damage with exit 2 (never "identical"), and nothing panics or
//! allocates what a flipped length field claims.
use std::path::Path;

use hal::XorShift64 as Rng;
use integration_tests::*;
use runlog::log::reader::{LogFile, ReadError, MAX_CHUNK_BYTES};
use runlog::replay::{replay, ReplayOptions};

const LOG: &str = "tests/corpus/rl_lab_estop_29dof.mcap";

fn committed_log() -> Vec<u8> {
    std::fs::read(repo_root().join(LOG)).expect("committed corpus log")
}

/// Top-level records as (offset, opcode, body range), by the MCAP spec alone.
fn records(b: &[u8]) -> Vec<(usize, u8, std::ops::Range<usize>)> {
    let mut out = Vec::new();
    let mut pos = 8;
    while pos + 9 <= b.len() - 8 {
        let len = u64::from_le_bytes(b[pos + 1..pos + 9].try_into().unwrap()) as usize;
        out.push((pos, b[pos], pos + 9..pos + 9 + len));
        pos += 9 + len;
    }
    out
}

/// What the reader makes of a damaged copy: `Ok(description)` when it names the damage.
fn named_damage(bytes: Vec<u8>) -> Result<String, String> {
    let log = match LogFile::from_bytes(Path::new("flipped.mcap"), bytes) {
        Ok(l) => l,
        Err(e @ ReadError::NotMcap { .. }) => return Ok(e.to_string()),
        Err(e) => return Err(format!("unexpected open error {e}")),
    };
    let _ = log.run_metadata();
    let end = log.scan(|_, _, _| {});
    match (end.damaged, end.truncated) {
        (Some(d), None) => Ok(d.to_string()),
        (d, t) => Err(format!("not named as damaged: damaged {d:?}, truncated {t:?}")),
    }
}

#[test]
fn the_committed_log_verifies() {
    let log = LogFile::from_bytes(Path::new(LOG), committed_log()).unwrap();
    let end = log.verify().expect("intact");
    assert!(end.truncated.is_none() && end.messages > 5_000, "{end:?}");
}

#[test]
fn every_single_byte_change_is_named_as_damage() {
    let good = committed_log();
    let mut rng = Rng(0xF11F_0022_0000_0001);
    let (mut in_chunks, mut elsewhere) = (0, 0);
    let chunks: Vec<_> = records(&good)
        .into_iter()
        .filter(|r| r.1 == 0x06)
        .map(|r| r.2)
        .collect();
    assert!(chunks.len() >= 2, "the log has {} chunks", chunks.len());
    let flips = 1500;
    for i in 0..flips {
        // Half anywhere in the file, half in the small non-chunk regions (headers, metadata,
        // indexes, summary, footer), where only the section CRCs can notice.
        let at = if i % 2 == 0 {
            rng.below(good.len())
        } else {
            loop {
                let at = rng.below(good.len());
                if !chunks.iter().any(|c| c.contains(&at)) {
                    break at;
                }
            }
        };
        if chunks.iter().any(|c| c.contains(&at)) {
            in_chunks += 1;
        } else {
            elsewhere += 1;
        }
        let mut bytes = good.clone();
        let old = bytes[at];
        bytes[at] = if rng.chance(50) {
            old ^ (1 << rng.below(8))
        } else {
            loop {
                let v = rng.next_u64() as u8;
                if v != old {
                    break v;
                }
            }
        };
        let verdict = std::panic::catch_unwind(|| named_damage(bytes))
            .unwrap_or_else(|_| panic!("the reader panicked on a change of byte {at}"));
        if let Err(e) = verdict {
            panic!("byte {at} changed {old:#04x}: {e}");
        }
    }
    eprintln!("{flips} single-byte changes, all named as damage ({in_chunks} in chunks, {elsewhere} elsewhere)");
    assert!(in_chunks > 300 && elsewhere > 600);
}

#[test]
fn a_bad_lz4_content_checksum_names_its_chunk() {
    let good = committed_log();
    let chunks: Vec<_> = records(&good).into_iter().filter(|r| r.1 == 0x06).collect();
    let (offset, _, body) = chunks[1].clone();
    let mut bytes = good.clone();
    // The chunk's records end with the LZ4 frame's 4-byte content checksum.
    bytes[body.end - 2] ^= 0x10;
    let log = LogFile::from_bytes(Path::new("x.mcap"), bytes).unwrap();
    let d = log.scan(|_, _, _| {}).damaged.expect("named");
    assert_eq!((d.chunk, d.offset), (Some(1), offset as u64), "{d}");
    assert!(d.what.contains("LZ4"), "{d}");
}

#[test]
fn a_flipped_size_is_refused_before_allocating() {
    let good = committed_log();
    let (_, _, body) = records(&good).into_iter().find(|r| r.1 == 0x06).unwrap();
    // uncompressed_size is the chunk's third u64; claim 2^60 bytes.
    let mut bytes = good.clone();
    bytes[body.start + 16..body.start + 24].copy_from_slice(&(1u64 << 60).to_le_bytes());
    let log = LogFile::from_bytes(Path::new("x.mcap"), bytes).unwrap();
    let d = log.scan(|_, _, _| {}).damaged.expect("named");
    assert!(d.what.contains(&MAX_CHUNK_BYTES.to_string()), "{d}");
    // A record length past the end of a finished file is damage, not a crash-truncated tail.
    let mut bytes = good.clone();
    bytes[body.start - 8..body.start].copy_from_slice(&u64::MAX.to_le_bytes());
    let log = LogFile::from_bytes(Path::new("x.mcap"), bytes).unwrap();
    let end = log.scan(|_, _, _| {});
    assert!(end.damaged.is_some() && end.truncated.is_none(), "{end:?}");
}

#[test]
fn replay_stops_at_damage_and_never_says_identical() {
    let good = committed_log();
    // Under the repository, so that replay finds the spec the logs pin (specs/...) above them.
    let dir = repo_root().join(format!("target/log-damage-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let mut rng = Rng(0xDA3A_6E00_0000_0022);
    let chunks: Vec<_> = records(&good).into_iter().filter(|r| r.1 == 0x06).collect();
    // A change in the last chunk: the ticks before it replay, and the report names the damage.
    let (_, _, last) = chunks.last().unwrap().clone();
    let mut bytes = good.clone();
    bytes[last.start + 200] ^= 0x01;
    let path = dir.join("late_damage.mcap");
    std::fs::write(&path, &bytes).unwrap();
    let opts = ReplayOptions::default();
    let r = replay(&path, &opts).expect("replays up to the damage");
    let d = r.damaged.as_ref().expect("damage reported");
    assert_eq!(d.chunk, Some(chunks.len() as u64 - 1), "{d}");
    assert!(r.divergence.is_none() && r.ticks > 100, "{r:?}");

    // Random changes: replay either refuses with the damage in its error, or reports it.
    for i in 0..60 {
        let mut bytes = good.clone();
        let at = rng.below(bytes.len());
        bytes[at] ^= 1 << rng.below(8);
        let path = dir.join(format!("flip{i}.mcap"));
        std::fs::write(&path, &bytes).unwrap();
        match replay(&path, &opts) {
            Ok(r) => assert!(r.damaged.is_some(), "byte {at}: replay passed a damaged log: {r:?}"),
            Err(e) => {
                let e = format!("{e:#}");
                assert!(e.contains("damaged"), "byte {at}: {e}");
            }
        }
    }

    // The command line: exit 2 and the damage named, from replay, log-info and plot.
    for (args, what) in [
        (vec!["replay"], "LOG DAMAGED"),
        (vec!["log-info"], "damaged"),
        (vec!["plot", "--out"], "damaged"),
    ] {
        let late = dir.join("late_damage.mcap");
        let mut a: Vec<String> = args.iter().map(|s| s.to_string()).collect();
        if args[0] == "plot" {
            a = vec![
                "plot".into(),
                late.display().to_string(),
                "--out".into(),
                dir.join("p.png").display().to_string(),
            ];
        } else {
            a.push(late.display().to_string());
        }
        let out = g1fw(&a.iter().map(String::as_str).collect::<Vec<_>>());
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{a:?}: {err}");
        assert!(err.contains(what) && err.contains("chunk"), "{a:?}: {err}");
        assert!(!err.contains("identical"), "{a:?}: {err}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}
