//! A run's table of chunks: each invocation that trained it (a "chunk" of a run that spans many
//! machines), with the env steps it went from and to, its wall time, the machine's CPU and thread
//! count, the commit that trained it, and a note (a new run, a resume, a change of recipe).
//! `chunks.json` for programs, `chunks.md` for people; rewritten at every checkpoint.
use std::path::Path;

use serde::{Deserialize, Serialize};

pub const CHUNKS_JSON: &str = "chunks.json";
pub const CHUNKS_MD: &str = "chunks.md";

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Chunk {
    /// When it started, UTC (`YYYY-MM-DD HH:MM`).
    pub started_utc: String,
    pub commit: String,
    pub cpu: String,
    pub threads: usize,
    pub from_iteration: usize,
    pub to_iteration: usize,
    pub from_env_steps: u64,
    pub to_env_steps: u64,
    pub wall_s: f64,
    pub note: String,
}

/// The chunks of the run in `dir` so far (none if it has no table).
pub fn read(dir: &Path) -> Vec<Chunk> {
    input_file::read_text_capped(&dir.join(CHUNKS_JSON), crate::MAX_TEXT_BYTES)
        .ok()
        .and_then(|t| serde_json::from_str(&t).ok())
        .unwrap_or_default()
}

/// Writes both forms of the table.
pub fn write(dir: &Path, chunks: &[Chunk]) -> anyhow::Result<()> {
    std::fs::write(dir.join(CHUNKS_JSON), serde_json::to_string_pretty(chunks)?)?;
    std::fs::write(dir.join(CHUNKS_MD), markdown(chunks))?;
    Ok(())
}

pub fn markdown(chunks: &[Chunk]) -> String {
    let mut s = String::from(
        "| started (UTC) | env steps | iterations | wall | env steps/s | CPU × threads | commit | note |\n|---|---|---|---|---|---|---|---|\n",
    );
    for c in chunks {
        let steps = c.to_env_steps - c.from_env_steps.min(c.to_env_steps);
        s += &format!(
            "| {} | {:.2} M → {:.2} M | {} → {} | {:.2} h | {:.0} | {} × {} | {} | {} |\n",
            c.started_utc,
            c.from_env_steps as f64 / 1e6,
            c.to_env_steps as f64 / 1e6,
            c.from_iteration,
            c.to_iteration,
            c.wall_s / 3600.0,
            steps as f64 / c.wall_s.max(1e-9),
            c.cpu,
            c.threads,
            c.commit,
            c.note
        );
    }
    s
}

/// The CPU's model name (`/proc/cpuinfo`), or `unknown`.
pub fn cpu_model() -> String {
    std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|t| {
            t.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split(':').nth(1))
                .map(|m| m.trim().to_string())
        })
        .unwrap_or_else(|| "unknown".into())
}

/// The commit of the checkout that holds `dir` (`git rev-parse --short HEAD`), with `+changes`
/// when tracked files outside `dir` differ from it (the run's own folder changes as it trains),
/// or `unknown` outside a checkout.
pub fn commit(dir: &Path) -> String {
    let git = |args: &[&str]| {
        std::process::Command::new("git")
            .arg("-C")
            .arg(dir)
            .args(args)
            .output()
            .ok()
            .filter(|o| o.status.success())
            .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
    };
    match git(&["rev-parse", "--short", "HEAD"]) {
        Some(h) if !h.is_empty() => {
            let dirty = git(&[
                "status",
                "--porcelain",
                "--untracked-files=no",
                "--",
                ":(top)",
                ":(exclude).",
            ])
            .is_some_and(|s| !s.is_empty());
            if dirty {
                format!("{h}+changes")
            } else {
                h
            }
        }
        _ => "unknown".into(),
    }
}

/// `YYYY-MM-DD HH:MM` of a Unix time, UTC (Howard Hinnant's days-to-civil).
pub fn utc(unix_s: u64) -> String {
    let days = (unix_s / 86_400) as i64;
    let (h, m) = ((unix_s % 86_400) / 3600, (unix_s % 3600) / 60);
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let mo = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(mo <= 2);
    format!("{y:04}-{mo:02}-{d:02} {h:02}:{m:02}")
}

/// Now, as [`utc`].
pub fn now_utc() -> String {
    let s = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    utc(s)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_commit_of_a_checkout_and_of_no_checkout() {
        let here = commit(Path::new(env!("CARGO_MANIFEST_DIR")));
        let hash = here.trim_end_matches("+changes");
        assert!(hash.len() >= 7 && hash.chars().all(|c| c.is_ascii_hexdigit()), "{here}");
        let outside = std::env::temp_dir().join(format!("g1_chunks_{}", std::process::id()));
        std::fs::create_dir_all(&outside).unwrap();
        assert_eq!(commit(&outside), "unknown");
        std::fs::remove_dir_all(&outside).unwrap();
    }

    #[test]
    fn dates_and_the_table() {
        assert_eq!(utc(0), "1970-01-01 00:00");
        assert_eq!(utc(1_796_601_600 + 3 * 3600 + 7 * 60), "2026-12-07 03:07");
        assert_eq!(utc(951_782_400), "2000-02-29 00:00");
        let c = Chunk {
            started_utc: "2026-12-07 16:40".into(),
            commit: "abc1234".into(),
            cpu: "AMD EPYC".into(),
            threads: 2,
            from_iteration: 0,
            to_iteration: 1000,
            from_env_steps: 0,
            to_env_steps: 3_072_000,
            wall_s: 600.0,
            note: "new run".into(),
        };
        let md = markdown(&[c]);
        assert!(
            md.contains(
                "| 2026-12-07 16:40 | 0.00 M → 3.07 M | 0 → 1000 | 0.17 h | 5120 | AMD EPYC × 2 | abc1234 | new run |"
            ),
            "{md}"
        );
    }
}
