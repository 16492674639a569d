//! `Runtime::save_snapshot` / `restore_snapshot`: what a split log's later files start from. A
//! snapshot restores into a runtime of the same spec and reads back the same; one from another
//! spec, a truncated one and one of another format are refused with the reason. (That a restored
//! runtime continues bit for bit is tested end to end: tests/tests/log_split.rs and the soak.)
use std::path::Path;

use control::controller::Controller;
use control::runtime::{Runtime, SNAPSHOT_FORMAT};
use control::spec::DeploySpec;
use snapshot::SnapshotError;

fn runtime(spec: &str) -> Runtime {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(spec);
    Runtime::new(Controller::new(DeploySpec::load(&path).unwrap()).unwrap())
}

#[test]
fn a_snapshot_restores_into_its_spec_and_is_refused_by_another() {
    let stairs = runtime("specs/stairs/g1_stairs_lstm.toml");
    let mut bytes = Vec::new();
    assert!(stairs.save_snapshot(&mut bytes));
    assert_eq!(bytes[..4], SNAPSHOT_FORMAT.to_le_bytes());

    let mut same = runtime("specs/stairs/g1_stairs_lstm.toml");
    same.restore_snapshot(&bytes).unwrap();
    let mut again = Vec::new();
    assert!(same.save_snapshot(&mut again));
    assert_eq!(again, bytes);

    // Another policy's observation history has another length: named, not misread.
    let mut other = runtime("specs/test/rl_lab_style.toml");
    let e = other.restore_snapshot(&bytes).unwrap_err();
    assert!(matches!(e, SnapshotError::Length { .. }), "{e}");

    let mut cut = runtime("specs/stairs/g1_stairs_lstm.toml");
    let e = cut.restore_snapshot(&bytes[..bytes.len() - 3]).unwrap_err();
    assert!(matches!(e, SnapshotError::Truncated { .. }), "{e}");

    let mut newer = bytes.clone();
    newer[..4].copy_from_slice(&(SNAPSHOT_FORMAT + 1).to_le_bytes());
    let e = runtime("specs/stairs/g1_stairs_lstm.toml")
        .restore_snapshot(&newer)
        .unwrap_err();
    assert_eq!(
        e,
        SnapshotError::Version {
            expected: SNAPSHOT_FORMAT,
            found: SNAPSHOT_FORMAT + 1
        }
    );
}
