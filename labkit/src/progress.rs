//! What the long-running tools (`g1-dataset`, `g1-train`) share on the terminal: one progress-bar
//! style and the default worker count.
use indicatif::{ProgressBar, ProgressStyle};

/// A bar over `total` units named `what` (hidden when `quiet`).
pub fn bar(total: usize, quiet: bool, what: &str) -> ProgressBar {
    if quiet {
        return ProgressBar::hidden();
    }
    let pb = ProgressBar::new(total as u64);
    pb.set_style(
        ProgressStyle::with_template(&format!(
            "{{elapsed_precise}} [{{bar:40}}] {{pos}}/{{len}} {what} ({{per_sec}}, eta {{eta}}) {{msg}}"
        ))
        .expect("valid template")
        .progress_chars("=> "),
    );
    pb
}

/// Worker threads by default: one per available core.
pub fn default_jobs() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}
