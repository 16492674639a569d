//! A run's recipe: `g1-train ppo`'s options as a TOML file, one key per option (its long name),
//! every value stated, defaults included, so a run reads the same whatever the defaults become.
//! A new run writes `recipe.toml` into its directory; `--recipe FILE` starts a run from one and
//! `--resume DIR` continues the run in DIR from its own, needing nothing else. Options given on
//! the command line win over the file's.
use std::collections::BTreeMap;
use std::ffi::{OsStr, OsString};
use std::path::{Path, PathBuf};

use anyhow::Context;
use clap::{ArgAction, Args as _, Command};

pub const RECIPE: &str = "recipe.toml";

/// Options that never go into a recipe: where, how long and on how many threads this invocation
/// runs. None of them changes what the run computes.
const RUN_CONTROL: &[&str] = &[
    "out",
    "resume",
    "recipe",
    "threads",
    "max_wall",
    "quiet",
    "accept_recipe_change",
    "help",
];

fn command() -> Command {
    super::ppo::Args::augment_args(Command::new("ppo").no_binary_name(true))
}

/// The long flag of an argument id (`max_wall` → `max-wall`).
fn flag(id: &str) -> String {
    id.replace('_', "-")
}

/// `g1-train ppo …` with `--resume DIR` or `--recipe FILE` expanded into the recipe's options
/// (and `--resume DIR` into `--out DIR`); any other command line comes back as it was.
pub fn expand(argv: Vec<OsString>) -> anyhow::Result<Vec<OsString>> {
    if argv.get(1).map(OsString::as_os_str) != Some(OsStr::new("ppo")) {
        return Ok(argv);
    }
    let value_of = |name: &str| -> Option<PathBuf> {
        let long = format!("--{name}");
        let eq = format!("--{name}=");
        argv.iter().enumerate().find_map(|(i, a)| {
            let a = a.to_string_lossy();
            if a == long {
                argv.get(i + 1).map(PathBuf::from)
            } else {
                a.strip_prefix(&eq).map(PathBuf::from)
            }
        })
    };
    let (file, out) = match (value_of("resume"), value_of("recipe")) {
        (Some(_), Some(_)) => anyhow::bail!("--resume DIR takes the run's own recipe (DIR/{RECIPE}): drop --recipe"),
        (Some(dir), None) => {
            let file = dir.join(RECIPE);
            anyhow::ensure!(
                file.is_file() && dir.join(train::ppo::runner::CHECKPOINT).is_file(),
                "--resume {}: no run there ({RECIPE} and {} are what a run directory holds); start one with --out",
                dir.display(),
                train::ppo::runner::CHECKPOINT
            );
            (file, Some(dir))
        }
        (None, Some(file)) => (file, None),
        (None, None) => return Ok(argv),
    };
    let given: Vec<String> = argv
        .iter()
        .filter_map(|a| {
            a.to_str()?
                .strip_prefix("--")
                .map(|f| f.split('=').next().unwrap_or(f).to_string())
        })
        .collect();
    let mut out_argv = argv.clone();
    if let Some(dir) = out {
        anyhow::ensure!(
            !given.iter().any(|g| g == "out"),
            "--resume DIR is the run's directory: drop --out"
        );
        out_argv.push("--out".into());
        out_argv.push(dir.into_os_string());
    }
    for (key, value) in read(&file)? {
        if given.contains(&key) {
            continue;
        }
        match value {
            None => {}
            Some(v) if v == "\u{0}flag" => out_argv.push(format!("--{key}").into()),
            Some(v) => {
                out_argv.push(format!("--{key}").into());
                out_argv.push(v.into());
            }
        }
    }
    Ok(out_argv)
}

/// The recipe at `file` as (option, value) pairs: `Some("\0flag")` for a flag that is set, `None`
/// for one that is not. Unknown keys and run-control keys are refused, naming them.
fn read(file: &Path) -> anyhow::Result<Vec<(String, Option<String>)>> {
    let text = input_file::read_text_capped(file, 1 << 20)
        .with_context(|| format!("reading the recipe {}", file.display()))?;
    let table: toml::Table =
        toml::from_str(&text).with_context(|| format!("the recipe {} is not TOML", file.display()))?;
    let cmd = command();
    let mut out = Vec::new();
    for (key, value) in table {
        let id = key.replace('-', "_");
        let arg = cmd.get_arguments().find(|a| a.get_id().as_str() == id).ok_or_else(|| {
            anyhow::anyhow!(
                "{}: `{key}` is not an option of g1-train ppo (see --help)",
                file.display()
            )
        })?;
        anyhow::ensure!(
            !RUN_CONTROL.contains(&id.as_str()),
            "{}: `{key}` says how this invocation runs, not what it trains; give it on the command line",
            file.display()
        );
        let is_flag = matches!(arg.get_action(), ArgAction::SetTrue);
        let v = match value {
            toml::Value::Boolean(b) if is_flag => b.then(|| "\u{0}flag".to_string()),
            toml::Value::String(s) if !is_flag => Some(s),
            toml::Value::Integer(i) if !is_flag => Some(i.to_string()),
            // Rust prints the shortest form that reads back as the same f64.
            toml::Value::Float(f) if !is_flag => Some(f.to_string()),
            other => anyhow::bail!(
                "{}: `{key}` = {other} is not a {}",
                file.display(),
                if is_flag { "true or false" } else { "number or string" }
            ),
        };
        out.push((flag(&id), v));
    }
    Ok(out)
}

/// The recipe of the options in `args` (what follows `ppo` on the expanded command line): every
/// option but the run-control ones, defaults included, as TOML.
pub fn text(args: &[OsString]) -> anyhow::Result<String> {
    let cmd = command();
    let m = cmd.clone().try_get_matches_from(args)?;
    let mut table = BTreeMap::new();
    for arg in cmd.get_arguments() {
        let id = arg.get_id().as_str();
        if RUN_CONTROL.contains(&id) {
            continue;
        }
        let value = if matches!(arg.get_action(), ArgAction::SetTrue) {
            toml::Value::Boolean(m.get_flag(id))
        } else {
            let Some(raw) = m.get_raw(id) else {
                continue; // an option without a default, not given
            };
            let raw: Vec<String> = raw.map(|r| r.to_string_lossy().into_owned()).collect();
            let joined = raw.join(",");
            if let Ok(i) = joined.parse::<i64>() {
                toml::Value::Integer(i)
            } else if let Some(f) = joined
                .parse::<f64>()
                .ok()
                .filter(|f| f.is_finite() && !joined.contains(','))
            {
                toml::Value::Float(f)
            } else {
                toml::Value::String(joined)
            }
        };
        table.insert(flag(id), value);
    }
    let body = toml::to_string(&table)?;
    Ok(format!(
        "# g1-train ppo's recipe: every option of the run (defaults included). `g1-train ppo --resume DIR`\n\
         # reads it; a change resumes only with --accept-recipe-change (a new row in the run's table).\n{body}"
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn os(v: &[&str]) -> Vec<OsString> {
        v.iter().map(OsString::from).collect()
    }

    #[test]
    fn a_written_recipe_expands_back_into_the_same_options() {
        let dir = std::env::temp_dir().join(format!("g1_recipe_{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let args = os(&[
            "--out",
            "x",
            "--lr",
            "3e-4",
            "--symmetry",
            "--actor-hidden",
            "256,128,128",
            "--threads",
            "1",
        ]);
        let t = text(&args).unwrap();
        assert!(t.contains("lr = 0.0003"), "{t}");
        assert!(t.contains("symmetry = true"), "{t}");
        assert!(t.contains("actor-hidden = \"256,128,128\""), "{t}");
        assert!(
            !t.contains("threads") && !t.contains("out ="),
            "run control stays out: {t}"
        );
        let file = dir.join(RECIPE);
        std::fs::write(&file, &t).unwrap();
        let mut argv = os(&["g1-train", "ppo", "--recipe"]);
        argv.push(file.clone().into());
        argv.extend(os(&["--out", "y", "--lr", "1e-3"]));
        let expanded = expand(argv).unwrap();
        let again = text(&expanded[2..]).unwrap();
        assert_eq!(
            again,
            t.replace("lr = 0.0003", "lr = 0.001"),
            "the command line's --lr wins"
        );
        // A key that is not an option, and one that is run control, are refused by name.
        std::fs::write(&file, "lrr = 1.0\n").unwrap();
        let e = expand(os(&["g1-train", "ppo", "--recipe", file.to_str().unwrap()]))
            .unwrap_err()
            .to_string();
        assert!(e.contains("`lrr` is not an option"), "{e}");
        std::fs::write(&file, "threads = 4\n").unwrap();
        let e = expand(os(&["g1-train", "ppo", "--recipe", file.to_str().unwrap()]))
            .unwrap_err()
            .to_string();
        assert!(e.contains("`threads` says how this invocation runs"), "{e}");
        std::fs::write(&file, "symmetry = 3\n").unwrap();
        let e = expand(os(&["g1-train", "ppo", "--recipe", file.to_str().unwrap()]))
            .unwrap_err()
            .to_string();
        assert!(e.contains("true or false"), "{e}");
        let e = expand(os(&[
            "g1-train",
            "ppo",
            "--resume",
            dir.join("nothing").to_str().unwrap(),
        ]))
        .unwrap_err()
        .to_string();
        assert!(e.contains("no run there"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
