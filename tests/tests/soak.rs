//! Three minutes of the soak (`integration_tests::soak`): five faults, one of each kind, each
//! tripping damping and recovered by an operator reset, with the controller's memory flat, its
//! tick timing steady and the log, split into files, replaying bit-exact file by file. The hour runs as a bench
//! (`cargo bench --workspace --bench soak`).
#![allow(clippy::disallowed_methods)]

use integration_tests::scratch_dir;
use integration_tests::soak::{check, soak, SoakPlan, FAULTS};

#[test]
fn three_minutes_of_faults_and_resets_leave_memory_flat_timing_steady_and_a_replayable_log() {
    let dir = scratch_dir("soak");
    let plan = SoakPlan {
        duration_s: 180.0,
        fault_every_s: 30.0,
        rss_every_s: 1.0,
        windows: 3,
        // About 60 MB in three minutes: four files or so.
        split_mb: 20.0,
    };
    let Some(f) = soak(&dir, plan) else { return };
    eprintln!("{}", serde_json::to_string_pretty(&f).unwrap());
    check(&f);
    assert_eq!(f.faults.len(), FAULTS.len(), "every kind of fault once: {f:#?}");
    assert!(f.log_files >= 3, "the log was split: {f:#?}");
    // Flat memory: nothing that grows per tick, per fault or per reset (the log writer's chunk
    // index grows by a few bytes per chunk, far under this).
    assert!(
        f.rss_growth_mib <= 2.0,
        "g1fw's memory grew {} MiB: {f:#?}",
        f.rss_growth_mib
    );
    // Steady timing: the last minute's median compute time is the first minute's, within noise.
    let (first, last) = (&f.timing[0], f.timing.last().unwrap());
    assert!(
        last.compute_p50_us <= 2.0 * first.compute_p50_us + 20.0,
        "tick compute time drifted: {first:?} → {last:?}"
    );
}
