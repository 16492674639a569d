//! One rule for every output of every binary (`output_file`): an output may not be an input, a file
//! an input names, or another output. This test reads every binary's and subcommand's options from
//! its own `--help` (the CLI definitions), finds the outputs among them, and points each at an input
//! of its command: every one must be refused by name, the input left as it was. An output flag the
//! table below does not know fails the test, so a new one cannot escape the rule.
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

use integration_tests::{built_bin, repo_root};

/// Flag names that write files, and help texts that start like an output's.
const OUTPUT_NAMES: &[&str] = &[
    "out",
    "report",
    "log",
    "plot",
    "profile-plot",
    "json",
    "markdown",
    "ready-file",
];
const OUTPUT_HELP: &[&str] = &["Write", "Record", "Draw", "Output", "Also write"];
/// Flags whose names look like outputs but are not files the program writes.
const NOT_OUTPUTS: &[&str] = &["g1-train export --data"];
/// Outputs of commands that read no file of their user's: nothing to overwrite.
const NO_INPUTS: &[&str] = &["g1-dataset eval-geometric --report"];

const BINARIES: &[&str] = &["g1fw", "g1-train", "g1-dataset", "g1-import", "g1-sim", "g1-can-emu"];

fn help(bin: &str, sub: Option<&str>) -> String {
    let mut c = Command::new(built_bin(bin));
    c.args(sub).arg("--help");
    let out = c.output().expect("runs");
    String::from_utf8_lossy(&out.stdout).to_string()
}

fn subcommands(text: &str) -> Vec<String> {
    let Some(start) = text.find("Commands:") else {
        return Vec::new();
    };
    text[start..]
        .lines()
        .skip(1)
        .take_while(|l| l.starts_with("  "))
        .filter_map(|l| l.split_whitespace().next())
        .filter(|s| *s != "help")
        .map(str::to_string)
        .collect()
}

/// `(flag, help text)` of every long option.
fn options(text: &str) -> Vec<(String, String)> {
    text.lines()
        .filter_map(|l| {
            let l = l.trim_start();
            let l = l
                .strip_prefix("-")
                .filter(|r| r.len() > 2 && r.as_bytes()[1] == b',')
                .map_or(l, |r| r[2..].trim_start());
            let rest = l.strip_prefix("--")?;
            let name: String = rest
                .chars()
                .take_while(|c| c.is_ascii_alphanumeric() || *c == '-')
                .collect();
            let after = &rest[name.len()..];
            let takes_value = after.starts_with(" <");
            let desc = after.split_once(">  ").map_or("", |(_, d)| d.trim()).to_string();
            takes_value.then_some((name, desc))
        })
        .collect()
}

/// Every output flag of every (sub)command, as `"bin [sub] --flag"`.
fn output_flags() -> Vec<String> {
    let mut found = Vec::new();
    for bin in BINARIES {
        let top = help(bin, None);
        let subs = subcommands(&top);
        let commands: Vec<Option<String>> = if subs.is_empty() {
            vec![None]
        } else {
            subs.into_iter().map(Some).collect()
        };
        for sub in commands {
            let text = help(bin, sub.as_deref());
            for (flag, desc) in options(&text) {
                let is_output =
                    OUTPUT_NAMES.contains(&flag.as_str()) || OUTPUT_HELP.iter().any(|w| desc.starts_with(w));
                let name = match &sub {
                    Some(s) => format!("{bin} {s} --{flag}"),
                    None => format!("{bin} --{flag}"),
                };
                if is_output && !NOT_OUTPUTS.contains(&name.as_str()) {
                    found.push(name);
                }
            }
        }
    }
    found
}

fn sha(p: &Path) -> Vec<u8> {
    std::fs::read(p).unwrap_or_default()
}

#[test]
fn no_output_flag_of_any_binary_overwrites_an_input() {
    let dir = std::env::temp_dir().join(format!("g1-outputs-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    // Inputs in a scratch directory: a refusal that fails must not damage the repository.
    let root = repo_root();
    let spec = dir.join("g1_stairs_lstm.toml");
    let weights = dir.join("g1_stairs_lstm.safetensors");
    std::fs::copy(root.join("specs/stairs/g1_stairs_lstm.toml"), &spec).unwrap();
    std::fs::copy(root.join("specs/stairs/g1_stairs_lstm.safetensors"), &weights).unwrap();
    let text = std::fs::read_to_string(&spec).unwrap();
    // The spec's other relative paths (the estimator's model) back to the repository.
    std::fs::write(&spec, text.replace("\"../../", &format!("\"{}/", root.display()))).unwrap();
    let can = dir.join("can.toml");
    std::fs::copy(root.join("specs/can/g1_12dof.toml"), &can).unwrap();
    let world = dir.join("world.toml");
    std::fs::copy(
        root.join("specs/worlds")
            .read_dir()
            .unwrap()
            .next()
            .unwrap()
            .unwrap()
            .path(),
        &world,
    )
    .unwrap();
    // An import writes policy.toml and policy.safetensors into --out: an input of that name there.
    let imp = dir.join("import");
    std::fs::create_dir_all(&imp).unwrap();
    let onnx = imp.join("policy.safetensors");
    std::fs::copy(&weights, &onnx).unwrap();
    let log = dir.join("run.mcap");
    let made = Command::new(built_bin("g1fw"))
        .args(["sim", "--model", "g1-12dof", "--duration", "0.1", "--quiet", "--log"])
        .arg(&log)
        .current_dir(&root)
        .output()
        .unwrap();
    assert!(made.status.success(), "{}", String::from_utf8_lossy(&made.stderr));

    let (i, o) = (imp.to_str().unwrap(), onnx.to_str().unwrap());
    let (s, w, c, l, d, wo) = (
        spec.to_str().unwrap(),
        weights.to_str().unwrap(),
        can.to_str().unwrap(),
        log.to_str().unwrap(),
        dir.to_str().unwrap(),
        world.to_str().unwrap(),
    );
    // Each output flag: a command that aims it at an input, and that input.
    let cases: BTreeMap<&str, (Vec<&str>, &str)> = BTreeMap::from([
        (
            "g1fw sim --log",
            (vec!["sim", "--spec", s, "--duration", "0.1", "--quiet", "--log", s], s),
        ),
        (
            "g1fw sim --report",
            (
                vec!["sim", "--spec", s, "--duration", "0.1", "--quiet", "--report", w],
                w,
            ),
        ),
        (
            "g1fw sim --plot",
            (vec!["sim", "--spec", s, "--duration", "0.1", "--quiet", "--plot", s], s),
        ),
        (
            "g1fw sim --profile-plot",
            (
                vec!["sim", "--spec", s, "--duration", "0.1", "--quiet", "--profile-plot", w],
                w,
            ),
        ),
        (
            "g1fw eval --report",
            (vec!["eval", "--spec", s, "--worlds", wo, "--quiet", "--report", wo], wo),
        ),
        (
            "g1fw run --log",
            (
                vec!["run", "--spec", s, "--dds", "lo", "--duration", "0.1", "--log", w],
                w,
            ),
        ),
        (
            "g1fw run --report",
            (
                vec![
                    "run",
                    "--spec",
                    s,
                    "--can-config",
                    c,
                    "--duration",
                    "0.1",
                    "--report",
                    c,
                ],
                c,
            ),
        ),
        ("g1fw replay --report", (vec!["replay", l, "--report", l], l)),
        ("g1fw plot --out", (vec!["plot", l, "--out", l], l)),
        ("g1fw bev --out", (vec!["bev", l, "--out", l], l)),
        ("g1-train fit --out", (vec!["fit", "--data", d, "--out", d], s)),
        (
            "g1-train export --out",
            (vec!["export", "--checkpoint", w, "--out", d], w),
        ),
        (
            "g1-train eval-terrain --report",
            (vec!["eval-terrain", "--weights", w, "--report", w], w),
        ),
        (
            "g1-train eval-terrain --plot",
            (vec!["eval-terrain", "--weights", w, "--plot", w], w),
        ),
        (
            "g1-train ppo --out",
            (vec!["ppo", "--spec", s, "--judge-every", "0", "--out", d], w),
        ),
        (
            "g1-train ppo-eval --json",
            (vec!["ppo-eval", "--spec", s, "--json", w], w),
        ),
        (
            "g1-train success-curve --out",
            (vec!["success-curve", "--point", &"1=", "--out", s], s),
        ),
        (
            "g1-train success-curve --markdown",
            (vec!["success-curve", "--point", &"1=", "--markdown", s], s),
        ),
        (
            "g1-train widen-actor --out",
            (
                vec![
                    "widen-actor",
                    "--actor",
                    w,
                    "--spec",
                    s,
                    "--hidden",
                    "256,128,128",
                    "--out",
                    w,
                ],
                w,
            ),
        ),
        (
            "g1-train average-actors --out",
            (vec!["average-actors", "--spec", s, "--out", w, w, w], w),
        ),
        (
            "g1-dataset export --out",
            (vec!["export", "--world", wo, "--out", d], wo),
        ),
        ("g1-can-emu --report", (vec!["--can-config", c, "--report", c], c)),
        (
            "g1-can-emu --ready-file",
            (vec!["--can-config", c, "--ready-file", c], c),
        ),
        (
            "g1-import rl-lab --out",
            (vec!["rl-lab", "--deploy", s, "--onnx", o, "--out", i], o),
        ),
        ("g1-import mjlab --out", (vec!["mjlab", "--onnx", o, "--out", i], o)),
        ("g1-import network --out", (vec!["network", o, "--out", i], o)),
    ]);
    let flags = output_flags();
    assert!(flags.len() >= 20, "found only {flags:?}");
    let unknown: Vec<&String> = flags
        .iter()
        .filter(|f| !cases.contains_key(f.as_str()) && !NO_INPUTS.contains(&f.as_str()))
        .collect();
    assert!(
        unknown.is_empty(),
        "output flags this test does not know (add a case that aims each at an input): {unknown:?}"
    );
    let mut failures = Vec::new();
    for flag in flags.iter().filter(|f| cases.contains_key(f.as_str())) {
        let (args, input) = &cases[flag.as_str()];
        let bin = flag.split(' ').next().unwrap();
        // success-curve's point names its report: the spec stands in for it.
        let args: Vec<String> = args
            .iter()
            .map(|a| if *a == "1=" { format!("1={s}") } else { a.to_string() })
            .collect();
        let before = sha(Path::new(input));
        let out = Command::new(built_bin(bin))
            .args(&args)
            .current_dir(&root)
            .env("G1_SIM_MODEL_CACHE", "")
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        let refused = !out.status.success() && (err.contains("is also") || err.contains("is the input"));
        if !refused || sha(Path::new(input)) != before {
            failures.push(format!(
                "{flag}: exit {:?}, input kept: {}: {}",
                out.status.code(),
                sha(Path::new(input)) == before,
                err.lines().last().unwrap_or("")
            ));
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
    // And the command that writes the spec's own weights never overwrites its checkpoint.
    let out = Command::new(built_bin("g1-train"))
        .args(["ppo-export", "--checkpoint", w, "--spec", s])
        .output()
        .unwrap();
    assert!(!out.status.success() && String::from_utf8_lossy(&out.stderr).contains("is also"));
    std::fs::remove_dir_all(&dir).unwrap();
    let _: PathBuf = dir;
}
