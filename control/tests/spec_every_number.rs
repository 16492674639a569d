//! Issue 30, "validation by principle": every number in a deploy spec is finite and inside a
//! documented range, or the spec is refused naming the field. Each float of the committed specs is
//! set in turn to NaN, +1e30 and −1e30: a spec that still loads with such a value is a gap.
use std::path::Path;

use control::spec::DeploySpec;

fn leaves(v: &toml::Value, path: String, out: &mut Vec<String>) {
    match v {
        toml::Value::Table(t) => {
            for (k, x) in t {
                leaves(
                    x,
                    if path.is_empty() {
                        k.clone()
                    } else {
                        format!("{path}.{k}")
                    },
                    out,
                );
            }
        }
        toml::Value::Array(a) => {
            for (i, x) in a.iter().enumerate() {
                leaves(x, format!("{path}[{i}]"), out);
            }
        }
        toml::Value::Float(_) => out.push(path),
        _ => {}
    }
}

fn set(v: &mut toml::Value, path: &str, x: f64) {
    let mut cur = v;
    for part in path.split('.') {
        let (key, idx) = match part.split_once('[') {
            Some((k, rest)) => (
                k,
                rest.trim_end_matches(']')
                    .split("][")
                    .map(|i| i.parse::<usize>().unwrap())
                    .collect(),
            ),
            None => (part, Vec::new()),
        };
        cur = cur.get_mut(key).unwrap();
        for i in idx {
            cur = cur.get_mut(i).unwrap();
        }
    }
    *cur = toml::Value::Float(x);
}

#[test]
fn no_float_of_a_spec_may_be_nan_or_absurd() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let mut gaps = Vec::new();
    for spec in ["specs/test/rl_lab_style.toml", "specs/stairs/g1_stairs_lstm.toml"] {
        let path = root.join(spec);
        let text = std::fs::read_to_string(&path).unwrap();
        let value: toml::Value = toml::from_str(&text).unwrap();
        let mut paths = Vec::new();
        leaves(&value, String::new(), &mut paths);
        assert!(paths.len() > 20, "{spec}: {} floats", paths.len());
        for p in &paths {
            for x in [f64::NAN, 1e30, -1e30] {
                let mut v = value.clone();
                set(&mut v, p, x);
                let t = toml::to_string(&v).unwrap();
                if DeploySpec::from_toml(&t, &path).is_ok() {
                    gaps.push(format!("{spec}: {p} = {x}"));
                }
            }
        }
    }
    assert!(gaps.is_empty(), "accepted:\n{}", gaps.join("\n"));
}
