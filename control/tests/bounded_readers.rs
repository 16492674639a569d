//! Issue 22, "bounded readers": sizes beyond the stated limits are refused with an error that names
//! the limit, before anything of that size is allocated or read.
use std::path::{Path, PathBuf};

use control::nn::{LayerDesc, Network, NetworkDesc, NnError, MAX_ACTIVATION, MAX_WEIGHTS_BYTES};
use control::spec::{DeploySpec, SpecError, MAX_OBSERVATION_DIM, MAX_OBS_HISTORY, MAX_SPEC_BYTES};

fn spec_text() -> String {
    std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../specs/test/rl_lab_style.toml")).unwrap()
}

fn invalid_field(text: &str) -> (String, String) {
    match DeploySpec::from_toml(text, Path::new("/nonexistent/spec.toml")) {
        Err(SpecError::Invalid { field, message, .. }) => (field, message),
        Err(e) => panic!("expected a field error, got {e}"),
        Ok(_) => panic!("spec accepted"),
    }
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("g1fw-bounded-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// The reproduction: a history whose size overflows panicked with "capacity overflow" (check-spec
/// too). Now each history is bounded and the sum is checked.
#[test]
fn observation_history_is_bounded_and_its_sum_cannot_overflow() {
    let text = spec_text();
    let first = "{ kind = \"base_ang_vel\", scale = 0.2, history = 5, clip = 100.0 }";
    assert!(text.contains(first));
    for huge in ["9223372036854775807", "6148914691236517206", "1001"] {
        let t = text.replace(first, &first.replace("history = 5", &format!("history = {huge}")));
        let (field, message) = invalid_field(&t);
        assert_eq!(field, "observation.terms[0].history", "{message}");
        assert!(message.contains(&MAX_OBS_HISTORY.to_string()), "{message}");
    }
    // Every term at the limit: within the per-term bound, over the total.
    let t = text.replace("history = 5", &format!("history = {MAX_OBS_HISTORY}"));
    let (field, message) = invalid_field(&t);
    assert_eq!(field, "observation", "{message}");
    assert!(message.contains(&MAX_OBSERVATION_DIM.to_string()), "{message}");
}

#[test]
fn an_oversized_spec_is_refused_before_parsing() {
    let mut text = spec_text();
    text.push_str(&format!("\n# {}\n", "x".repeat(MAX_SPEC_BYTES)));
    let e = DeploySpec::from_toml(&text, Path::new("big.toml"))
        .unwrap_err()
        .to_string();
    assert!(e.contains(&MAX_SPEC_BYTES.to_string()), "{e}");
}

fn one_layer() -> NetworkDesc {
    NetworkDesc {
        input: 4,
        input_shape: None,
        layers: vec![LayerDesc::Linear {
            weight: "w".into(),
            bias: "b".into(),
        }],
    }
}

/// The reproduction: a 2 GB weight file was read whole (5.75 GB of RSS). A sparse file over the
/// limit is refused from its size, without reading it; a device that never ends, at the limit.
#[test]
fn weight_files_over_the_limit_are_not_read() {
    let dir = scratch("weights");
    let big = dir.join("big.safetensors");
    std::fs::File::create(&big)
        .unwrap()
        .set_len(MAX_WEIGHTS_BYTES + 1)
        .unwrap();
    let Err(e) = Network::load(&one_layer(), &big) else {
        panic!("accepted")
    };
    assert!(matches!(e, NnError::Io { .. }), "{e:?}");
    let s = format!("{e}: {}", std::error::Error::source(&e).unwrap());
    assert!(s.contains(&MAX_WEIGHTS_BYTES.to_string()), "{s}");
    std::fs::remove_dir_all(&dir).unwrap();
    if Path::new("/dev/zero").exists() {
        let e = control::read_capped(Path::new("/dev/zero"), 1 << 20).unwrap_err();
        // A device is refused as such before a byte is read.
        assert_eq!(e.kind(), std::io::ErrorKind::InvalidInput, "{e}");
    }
}

#[test]
fn activations_over_the_limit_are_refused_before_allocation() {
    let desc = NetworkDesc {
        input: MAX_ACTIVATION + 1,
        ..one_layer()
    };
    let Err(e) = Network::from_safetensors_bytes(&desc, b"") else {
        panic!("accepted")
    };
    assert!(matches!(e, NnError::TooLarge { .. }), "{e:?}");
    // A 1x1 convolution fanning one channel out to 2^13 over a 1x2^12 image: 2^25 outputs from a
    // weight file of 64 KB.
    let (cout, width) = (1usize << 13, 1usize << 12);
    let w: Vec<u8> = (0..cout).flat_map(|_| 0.5f32.to_le_bytes()).collect();
    let b: Vec<u8> = (0..cout).flat_map(|_| 0.0f32.to_le_bytes()).collect();
    let views = [
        (
            "w",
            safetensors::tensor::TensorView::new(safetensors::Dtype::F32, vec![cout, 1, 1, 1], &w).unwrap(),
        ),
        (
            "b",
            safetensors::tensor::TensorView::new(safetensors::Dtype::F32, vec![cout], &b).unwrap(),
        ),
    ];
    let bytes = safetensors::serialize(views, &None).unwrap();
    let desc = NetworkDesc {
        input: width,
        input_shape: Some(vec![1, 1, width]),
        layers: vec![LayerDesc::Conv2d {
            weight: "w".into(),
            bias: "b".into(),
            stride: 1,
            padding: 0,
        }],
    };
    let Err(e) = Network::from_safetensors_bytes(&desc, &bytes) else {
        panic!("accepted")
    };
    assert!(matches!(e, NnError::TooLarge { .. }), "{e:?}");
    assert!(e.to_string().contains(&MAX_ACTIVATION.to_string()), "{e}");
}

/// Issue 30: a FIFO named as an input blocked `open()` forever, and `/dev/zero` as a schedule was
/// read until memory ran out. Every reader now refuses what is not a regular file, saying what it is.
#[test]
fn fifos_devices_and_directories_are_refused_as_inputs_without_blocking() {
    let dir = scratch("fifo");
    let fifo = dir.join("input.fifo");
    let c = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
    // SAFETY: a valid NUL-terminated path; mkfifo only creates a file system node.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
    let (tx, rx) = std::sync::mpsc::channel();
    let f = fifo.clone();
    std::thread::spawn(move || {
        let spec = DeploySpec::load(&f)
            .map(|_| ())
            .map_err(|e| format!("{e}: {:?}", std::error::Error::source(&e)));
        let chain = |e: &dyn std::error::Error| format!("{e}: {}", e.source().map_or(String::new(), |s| s.to_string()));
        let schedule = control::operator::CommandSchedule::load(&f)
            .map(|_| ())
            .map_err(|e| chain(&e));
        let zero = control::operator::CommandSchedule::load(Path::new("/dev/zero"))
            .map(|_| ())
            .map_err(|e| chain(&e));
        let weights = control::read_capped(&f, MAX_WEIGHTS_BYTES)
            .map(|_| ())
            .map_err(|e| e.to_string());
        tx.send((spec, schedule, zero, weights)).unwrap();
    });
    let (spec, schedule, zero, weights) = rx
        .recv_timeout(std::time::Duration::from_secs(20))
        .expect("a reader blocked on a FIFO");
    for r in [&spec, &schedule, &weights] {
        let e = r.as_ref().unwrap_err();
        assert!(e.contains("a FIFO (named pipe), not a regular file"), "{e}");
    }
    assert!(zero.unwrap_err().contains("a character device"));
    std::fs::remove_dir_all(&dir).unwrap();
}
