//! The wireless remote's 40 bytes against unitree_sdk2py's own reader and writer
//! (`utils/joystick.py`, tests/python/remote_peer.py): readings it writes decode here to the same
//! buttons and sticks, and readings written here read there as the same buttons.
use integration_tests::{python_json, venv_python};
use sensor_io::unitree_hg::remote::{Button, Remote};

/// joystick.py's names for the buttons, and ours.
const NAMES: [(&str, Button); 14] = [
    ("LT", Button::L2),
    ("RT", Button::R2),
    ("back", Button::Select),
    ("start", Button::Start),
    ("LB", Button::L1),
    ("RB", Button::R1),
    ("left", Button::Left),
    ("down", Button::Down),
    ("right", Button::Right),
    ("up", Button::Up),
    ("Y", Button::Y),
    ("X", Button::X),
    ("B", Button::B),
    ("A", Button::A),
];

#[test]
fn remote_bytes_agree_with_unitree_sdk2py() {
    let Some(py) = venv_python("the remote peer (unitree_sdk2py's joystick.py)") else {
        return;
    };
    let made = python_json(&py, "remote_peer.py", &["make", "7", "200"]);
    let made = made.as_array().unwrap();
    assert_eq!(made.len(), 200);
    let mut ours_hex = Vec::new();
    for m in made {
        let bytes: Vec<u8> = m["bytes"]
            .as_array()
            .unwrap()
            .iter()
            .map(|b| b.as_u64().unwrap() as u8)
            .collect();
        let r = Remote::decode(&bytes.clone().try_into().unwrap());
        for (name, b) in NAMES {
            assert_eq!(r.pressed(b), m["buttons"][name].as_bool().unwrap(), "{name} in {m}");
        }
        for (axis, v) in [("lx", r.lx), ("ly", r.ly), ("rx", r.rx), ("ry", r.ry)] {
            let want = m["sticks"][axis].as_f64().unwrap() as f32;
            assert_eq!(v, want, "{axis} in {m}");
        }
        // And back: ours written, theirs read.
        ours_hex.push(r.encode().iter().map(|b| format!("{b:02x}")).collect::<String>());
    }
    let read = python_json(
        &py,
        "remote_peer.py",
        &[&["read".to_string()][..], &ours_hex[..]].concat(),
    );
    for (m, theirs) in made.iter().zip(read.as_array().unwrap()) {
        for (name, _) in NAMES {
            assert_eq!(theirs[name], m["buttons"][name], "{name}");
        }
    }
}
