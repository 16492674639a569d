//! CI smoke run of the whole training path on a tiny rendered dataset: export → fit a few steps
//! (the loss goes down) → fold → the firmware loads it → `g1-train eval-terrain` reports.
use std::path::PathBuf;
use std::process::Command;

use candle_core::Device;
use train::cnn::data::{split_by_world, Dataset};
use train::cnn::dataset::{export, DatasetConfig, ExportConfig, WorldSet};
use train::cnn::fit::{fit, FitConfig};

fn temp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("g1-train-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

#[test]
fn tiny_training_run_lowers_the_loss_and_exports_a_loadable_network() {
    let data = temp("smoke-data");
    export(
        &ExportConfig {
            worlds: WorldSet::Random {
                first_seed: 0,
                count: 6,
            },
            poses_per_world: 4,
            shard_size: 16,
            out: data.clone(),
            force: false,
            jobs: 2,
            // The memory's render path (the firmware's default may be single-frame).
            dataset: DatasetConfig {
                memory: train::cnn::dataset::MemoryConfig::DEFAULT,
                ..DatasetConfig::default()
            },
        },
        &|| {},
    )
    .unwrap();
    let ds = Dataset::load_dir(&data).unwrap();
    assert_eq!(ds.len(), 24);
    bev_coverage_script_reads_the_export(&data);
    let (tr, val) = split_by_world(&ds, 0.2);
    let out = temp("smoke-out");
    std::fs::create_dir_all(&out).unwrap();
    let checkpoint = out.join("checkpoint.safetensors");
    let cfg = FitConfig {
        epochs: 12,
        batch: 12,
        lr: 3e-3,
        mirror: false,
        checkpoint: Some(checkpoint.clone()),
        ..FitConfig::default()
    };
    let mut losses = Vec::new();
    let (vm, _model, log) = fit(
        &cfg,
        &ds,
        &tr,
        &val,
        &Device::Cpu,
        &mut |_, _, l| losses.push(l),
        &mut |_| {},
    )
    .unwrap();
    assert!(losses.len() >= 12, "{} steps", losses.len());
    let k = 3;
    let first: f64 = losses[..k].iter().sum::<f64>() / k as f64;
    let last: f64 = losses[losses.len() - k..].iter().sum::<f64>() / k as f64;
    assert!(last < 0.7 * first, "loss {first:.3} -> {last:.3}: {losses:?}");
    assert!(log.iter().all(|e| e.train.total.is_finite()));

    // The per-epoch checkpoint holds the final weights (an interrupted run resumes from it).
    let saved = candle_core::safetensors::load(&checkpoint, &Device::Cpu).unwrap();
    let vars = vm.data().lock().unwrap();
    assert_eq!(saved.len(), vars.len());
    for (name, var) in vars.iter() {
        let a = var.as_tensor().flatten_all().unwrap().to_vec1::<f32>().unwrap();
        let b = saved[name].flatten_all().unwrap().to_vec1::<f32>().unwrap();
        assert_eq!(a, b, "{name}");
    }
    drop(vars);
    assert!(!out.join("checkpoint.safetensors.partial").exists());

    // A fine-tune of the committed export with BatchNorm frozen: its running statistics stay
    // what the unfold set (they are not parameters), and the weights move.
    let export = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../control/weights/terrain_cnn.safetensors");
    let tune = FitConfig {
        epochs: 1,
        batch: 12,
        lr: 1e-3,
        mirror: false,
        max_steps: 2,
        init: Some(export.clone()),
        freeze_bn: true,
        ..FitConfig::default()
    };
    let (tuned, _, _) = fit(&tune, &ds, &tr, &val, &Device::Cpu, &mut |_, _, _| {}, &mut |_| {}).unwrap();
    let committed = candle_core::safetensors::load(&export, &Device::Cpu).unwrap();
    let tv = tuned.data().lock().unwrap();
    for (name, var) in tv.iter() {
        let v = var.as_tensor().flatten_all().unwrap().to_vec1::<f32>().unwrap();
        if name.ends_with("running_mean") {
            assert!(v.iter().all(|&x| x == 0.0), "{name} moved");
        } else if name.ends_with("running_var") {
            assert!(
                v.iter().all(|&x| x == (1.0 - train::cnn::model::BN_EPS) as f32),
                "{name} moved"
            );
        }
    }
    let w0 = committed["head.weight"]
        .flatten_all()
        .unwrap()
        .to_vec1::<f32>()
        .unwrap();
    let w1 = tv["head.weight"]
        .as_tensor()
        .flatten_all()
        .unwrap()
        .to_vec1::<f32>()
        .unwrap();
    assert!(w0 != w1, "two steps moved nothing");
    drop(tv);

    // Fold and write; the firmware's loader accepts it and computes a token.
    let sha = train::cnn::export::fold(&vm)
        .unwrap()
        .write(&out, &Default::default())
        .unwrap();
    let mut net = control::terrain_net::TerrainNet::load(
        &out.join(train::cnn::export::DESC_FILE),
        &out.join(train::cnn::export::WEIGHTS_FILE),
    )
    .unwrap();
    assert_eq!(net.weights_sha256(), sha);
    let mut grid = Box::new(sensor_io::bev::BevGrid::zeroed());
    grid.data.copy_from_slice(ds.grid(0));
    assert!(net.estimate(&grid, 0.0).is_some());

    // The CLI evaluates it next to the baseline and writes the report the issue asks for.
    let report = out.join("eval.json");
    let plot = out.join("eval.png");
    let o = Command::new(env!("CARGO_BIN_EXE_g1-train"))
        .args([
            "eval-terrain",
            "--worlds",
            "2",
            "--poses-per-world",
            "2",
            "--quiet",
            "--weights",
        ])
        .arg(&out)
        .arg("--report")
        .arg(&report)
        .arg("--plot")
        .arg(&plot)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(&report).unwrap()).unwrap();
    for who in ["cnn", "baseline"] {
        for key in ["mae_h_cm", "mae_d_cm", "mae_yaw_deg", "class_acc"] {
            assert!(v[who][key].is_number(), "{who}.{key} in {v}");
        }
    }
    assert_eq!(v["cnn"]["samples"], 4);
    assert_eq!(&std::fs::read(&plot).unwrap()[1..4], b"PNG");
    assert_eq!(&std::fs::read(out.join("eval_by_riser.png")).unwrap()[1..4], b"PNG");
    // Every stairs sample sits in one riser-distance bin (the box spans -0.5..1.5 m).
    let stairs = v["cnn"]["stairs_samples"].as_u64().unwrap();
    let binned: u64 = v["by_riser_ahead"]
        .as_array()
        .unwrap()
        .iter()
        .map(|b| b["samples"].as_u64().unwrap())
        .sum();
    assert_eq!(binned, stairs, "{}", v["by_riser_ahead"]);
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(
        stdout.contains("class accuracy") && stdout.contains("geometric") && stdout.contains("riser ahead"),
        "{stdout}"
    );
    std::fs::remove_dir_all(&data).ok();
    std::fs::remove_dir_all(&out).ok();
}

#[test]
fn eval_terrain_accepts_scenario_files_and_names_bad_ones() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..");
    let scenario = root.join("specs/worlds/stairs_down_steep.toml");
    let out = temp("scen");
    std::fs::create_dir_all(&out).unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_g1-train"))
        .args(["eval-terrain", "--poses-per-world", "1", "--quiet", "--worlds"])
        .arg(format!("{},stairs-up", scenario.display()))
        .arg("--plot")
        .arg(out.join("p.png"))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(String::from_utf8_lossy(&o.stdout).contains("stairs_down_steep.toml, stairs-up"));
    let o = Command::new(env!("CARGO_BIN_EXE_g1-train"))
        .args(["eval-terrain", "--worlds", "no_such_world.toml", "--quiet", "--plot"])
        .arg(out.join("q.png"))
        .output()
        .unwrap();
    assert!(!o.status.success());
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("no_such_world"),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    std::fs::remove_dir_all(&out).ok();
}

/// `scripts/bev_coverage.py` on the smoke export: the BEV memory fills the lidar's blind disc ahead
/// of the robot (a single frame leaves it empty), and the far ring is seen.
fn bev_coverage_script_reads_the_export(data: &std::path::Path) {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..");
    let py = root.join(".venv/bin/python");
    if !py.is_file() {
        let msg =
            "SKIP: scripts/bev_coverage.py needs the project's Python environment (.venv); run scripts/install.sh";
        assert!(std::env::var_os("CI").is_none(), "{msg} - and CI must have it");
        eprintln!("\n!!!!!!!! {msg} !!!!!!!!\n");
        return;
    }
    let o = Command::new(py)
        .arg(root.join("scripts/bev_coverage.py"))
        .arg(data)
        .output()
        .unwrap();
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{out}{}", String::from_utf8_lossy(&o.stderr));
    let share = |row: &str| -> f64 {
        let line = out
            .lines()
            .find(|l| l.trim_start().starts_with(row))
            .unwrap_or_else(|| panic!("{row} in {out}"));
        line.split_whitespace().rev().nth(1).unwrap().parse().unwrap()
    };
    assert!(share("x +0.3..+0.4 m") > 30.0, "{out}");
    assert!(share("r 1.4-1.5 m") > 10.0, "{out}");
}

/// Empty or wrapping requests are errors (not "MAE 0.000"), and nothing lands in the working
/// directory unless asked for (the plots used to default to ./eval_terrain.png).
#[test]
fn eval_terrain_refuses_empty_requests_and_writes_only_what_it_is_asked() {
    let cwd = temp("cwd");
    std::fs::create_dir_all(&cwd).unwrap();
    let run = |args: &[&str]| {
        Command::new(env!("CARGO_BIN_EXE_g1-train"))
            .arg("eval-terrain")
            .args(args)
            .current_dir(&cwd)
            .output()
            .unwrap()
    };
    let o = run(&["--worlds", "2", "--poses-per-world", "0", "--quiet"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("--poses-per-world 0"), "{err}");
    let o = run(&["--worlds", "2", "--seed", &u64::MAX.to_string(), "--quiet"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("u64"), "{err}");
    let o = run(&["--worlds", "0", "--quiet"]);
    assert!(!o.status.success());
    let o = run(&["--worlds", "1", "--poses-per-world", "1", "--quiet"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let left: Vec<_> = std::fs::read_dir(&cwd)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert!(
        left.is_empty(),
        "eval-terrain wrote {left:?} into its working directory"
    );
    std::fs::remove_dir_all(&cwd).ok();
}

/// `fit` never replaces an earlier run or one of its own inputs unless told to (issue 22). The
/// checks come before the dataset is read.
#[test]
fn fit_refuses_to_overwrite_a_run_or_its_inputs() {
    let out = temp("fit-out");
    std::fs::create_dir_all(&out).unwrap();
    std::fs::write(out.join("checkpoint.safetensors"), b"an earlier run").unwrap();
    let fit = |args: &[&str]| {
        let o = Command::new(env!("CARGO_BIN_EXE_g1-train"))
            .arg("fit")
            .args(args)
            .output()
            .unwrap();
        assert!(!o.status.success());
        String::from_utf8_lossy(&o.stderr).into_owned()
    };
    let o = out.to_str().unwrap();
    let e = fit(&["--data", "/nonexistent/data", "--out", o]);
    assert!(e.contains("not empty") && e.contains("--force"), "{e}");
    let e = fit(&["--data", o, "--out", o, "--force"]);
    assert!(e.contains("also a --data directory"), "{e}");
    let init = out.join("checkpoint.safetensors");
    let e = fit(&[
        "--data",
        "/nonexistent/data",
        "--out",
        o,
        "--force",
        "--init",
        init.to_str().unwrap(),
    ]);
    // The run's directory holds the checkpoint it would write over (output_file's rule).
    assert!(e.contains("is also the directory of --init"), "{e}");
    // An exported network is fine-tuned only with BatchNorm frozen.
    let export = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../control/weights/terrain_cnn.safetensors");
    let e = fit(&[
        "--data",
        "/nonexistent/data",
        "--out",
        temp("fit-export").to_str().unwrap(),
        "--init",
        export.to_str().unwrap(),
    ]);
    assert!(e.contains("--freeze-bn"), "{e}");
    assert_eq!(std::fs::read(&init).unwrap(), b"an earlier run");
    std::fs::remove_dir_all(&out).ok();
}

/// `--rate-std` and `--rate-hold` act on the gait clock's rate output: a spec without `[phase]
/// rate` is refused by name before any environment is built, as are a zero hold and a bad σ.
#[test]
fn ppo_refuses_rate_exploration_without_a_rate_output() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..");
    let out = temp("rate_refused");
    let run = |extra: &[&str]| {
        let o = Command::new(env!("CARGO_BIN_EXE_g1-train"))
            .args(["ppo", "--quiet", "--judge-every", "0", "--spec"])
            .arg(root.join("specs/stairs/g1_stairs_lstm.toml"))
            .arg("--out")
            .arg(&out)
            .args(extra)
            .output()
            .unwrap();
        assert!(!o.status.success(), "{extra:?} was accepted");
        String::from_utf8_lossy(&o.stderr).into_owned()
    };
    let e = run(&["--rate-hold", "25"]);
    assert!(e.contains("[phase] rate") && e.contains("g1_stairs_lstm.toml"), "{e}");
    let e = run(&["--rate-std", "0.3"]);
    assert!(e.contains("[phase] rate"), "{e}");
    let e = run(&["--rate-hold", "0"]);
    assert!(e.contains("--rate-hold must be 1 to 10000"), "{e}");
    let e = run(&["--rate-std=-1"]);
    assert!(e.contains("--rate-std"), "{e}");
    assert!(!out.join("checkpoint.safetensors").exists());
    std::fs::remove_dir_all(&out).ok();
}
