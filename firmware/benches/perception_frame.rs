//! Terrain-CNN perception frame: our `control::nn` executor (with `conv2d`) versus ONNX Runtime
//! on the same network, and the whole frame (Livox packets -> frame -> BEV -> CNN -> token).
//!
//! Plain bench binary (`harness = false`): `cargo bench -p firmware --bench perception_frame`.
//!
//! - The network: `control/weights/terrain_cnn.toml` (a `NetworkDesc` at top level) and
//!   `control/weights/terrain_cnn.safetensors` when both exist; otherwise the paper's shape
//!   (6x60x60 -> conv 24/48/128, k3 s2 p1, ReLU -> fc 8192->128 -> ReLU -> head 128->7) with
//!   random weights, said loudly on stderr. Timing does not depend on the weight values.
//! - (a) `Network::step` alone on a realistic BEV; the portable kernels as well where the CPU
//!   has AVX2 (aarch64 boards run the portable kernels).
//! - (b) one perception frame: ~20,000 points of a staircase ahead (ground, 0.15 m risers every
//!   0.3 m from 0.8 m, mm noise) encoded as MID-360 packets -> `FrameAssembler` -> `BevBuilder`
//!   -> CNN -> token (`estimator::terrain_cnn::decode`: argmax of the class logits, h, d, yaw),
//!   per frame, with the stages timed separately as well.
//! - (c) `scripts/bench/ort_terrain_cnn.py` (repo `.venv`): the same network as an ONNX graph
//!   from the same safetensors, checked against our output on the same BEV (<= 1e-4), timed with
//!   1 thread and ORT's default threading. Prints the ratios ours/ORT (target <= 1.0).
//!
//! Every timing is the median (and p99, min) of individually timed iterations after warm-up;
//! on a loaded machine the min is the better estimate of the uncontended cost.
// Benchmark inputs come from std's math on the host; this never runs on the robot.
#![allow(clippy::disallowed_methods)]

mod common;

use common::{loud, percentile};
use control::nn::{LayerDesc, Network, NetworkDesc};
use estimator::terrain_cnn::decode;
use hal::LIDAR_FRAME_CAP;
use hal::{LidarPoint, TerrainToken, XorShift64 as Rng};
use safetensors::tensor::{Dtype, TensorView};
use sensor_io::bev::{BevBuilder, BevGrid, MountPose, RobotFrame, SelfFilter, BEV_CELLS, BEV_LEN, CH_DENSITY};
use sensor_io::livox::{FrameAssembler, PacketWriter};
use std::ffi::OsStr;
use std::hint::black_box;
use std::path::{Path, PathBuf};
use std::time::Instant;

const CNN_WARMUP: usize = 300;
const CNN_ITERS: usize = 3_000;
const FRAME_WARMUP: usize = 200;
const FRAME_ITERS: usize = 2_000;
const N_POINTS: usize = 20_000;
const CNN_COLD_ITERS: usize = 300;
/// Twice this machine's 32 MB last-level cache.
const EVICT_BYTES: usize = 64 << 20;

// ---------------------------------------------------------------------------------------------
// The network: a description plus safetensors bytes, from files or random.

/// A network description with its weight file's bytes: everything needed to build our
/// [`Network`] and, from the same two things, the ONNX baseline.
struct CnnModel {
    desc: NetworkDesc,
    weights: Vec<u8>,
    /// Where the weights live on disk (the ORT script reads them), if they do.
    weights_path: Option<PathBuf>,
    origin: String,
}

impl CnnModel {
    /// `toml` (a `NetworkDesc` at top level) and `safetensors`, when both exist.
    fn from_files(toml_path: &Path, weights_path: &Path) -> Option<Result<Self, String>> {
        if !(toml_path.is_file() && weights_path.is_file()) {
            return None;
        }
        let load = || -> Result<Self, String> {
            let text = std::fs::read_to_string(toml_path).map_err(|e| format!("{}: {e}", toml_path.display()))?;
            let desc: NetworkDesc = toml::from_str(&text).map_err(|e| format!("{}: {e}", toml_path.display()))?;
            let weights = std::fs::read(weights_path).map_err(|e| format!("{}: {e}", weights_path.display()))?;
            Ok(Self {
                desc,
                weights,
                weights_path: Some(weights_path.to_path_buf()),
                origin: format!("{} + {}", toml_path.display(), weights_path.display()),
            })
        };
        Some(load())
    }

    /// The paper's terrain CNN (BatchNorm folded) with uniform random weights of fan-in scale.
    fn random(seed: u64) -> Self {
        let mut rng = Rng(seed);
        let tensors: Vec<(&str, Vec<usize>)> = vec![
            ("conv1.weight", vec![24, 6, 3, 3]),
            ("conv1.bias", vec![24]),
            ("conv2.weight", vec![48, 24, 3, 3]),
            ("conv2.bias", vec![48]),
            ("conv3.weight", vec![128, 48, 3, 3]),
            ("conv3.bias", vec![128]),
            ("fc.weight", vec![128, 8192]),
            ("fc.bias", vec![128]),
            ("head.weight", vec![7, 128]),
            ("head.bias", vec![7]),
        ];
        let data: Vec<Vec<u8>> = tensors
            .iter()
            .map(|(_, shape)| {
                let n: usize = shape.iter().product();
                let scale = 1.0 / (shape[1..].iter().product::<usize>().max(1) as f32).sqrt();
                (0..n).flat_map(|_| (scale * rng.signed()).to_le_bytes()).collect()
            })
            .collect();
        let views: Vec<(&str, TensorView<'_>)> = tensors
            .iter()
            .zip(&data)
            .map(|((name, shape), d)| (*name, TensorView::new(Dtype::F32, shape.clone(), d).expect("sizes")))
            .collect();
        let weights = safetensors::serialize(views, &None).expect("serialize");
        let conv = |name: &str| LayerDesc::Conv2d {
            weight: format!("{name}.weight"),
            bias: format!("{name}.bias"),
            stride: 2,
            padding: 1,
        };
        let linear = |name: &str| LayerDesc::Linear {
            weight: format!("{name}.weight"),
            bias: format!("{name}.bias"),
        };
        let desc = NetworkDesc {
            input: 6 * 60 * 60,
            input_shape: Some(vec![6, 60, 60]),
            layers: vec![
                conv("conv1"),
                LayerDesc::Relu,
                conv("conv2"),
                LayerDesc::Relu,
                conv("conv3"),
                LayerDesc::Relu,
                linear("fc"),
                LayerDesc::Relu,
                linear("head"),
            ],
        };
        Self {
            desc,
            weights,
            weights_path: None,
            origin: format!("RANDOM weights (seed {seed:#x}), paper shapes"),
        }
    }

    fn network(&self) -> Network {
        Network::from_safetensors_bytes(&self.desc, &self.weights)
            .unwrap_or_else(|e| panic!("terrain CNN ({}) does not load: {e}", self.origin))
    }

    /// The weight file's path, writing the bytes into `dir` first if they only live in memory.
    fn weights_file(&self, dir: &Path) -> std::io::Result<PathBuf> {
        match &self.weights_path {
            Some(p) => Ok(p.clone()),
            None => {
                let p = dir.join("weights.safetensors");
                std::fs::write(&p, &self.weights)?;
                Ok(p)
            }
        }
    }
}

/// Roughly normal (sum of four uniforms), standard deviation `sigma`.
fn noise(rng: &mut Rng, sigma: f32) -> f32 {
    let s: f32 = (0..4).map(|_| rng.signed()).sum();
    s * sigma * (3.0f32 / 4.0).sqrt()
}

// ---------------------------------------------------------------------------------------------
// The scene: a staircase ahead, as the MID-360 would send it.

const STEP_H: f32 = 0.15;
const STEP_D: f32 = 0.30;
const FIRST_RISER_X: f32 = 0.8;
const N_STEPS: usize = 4;

/// Ground height (robot frame, ground under the robot at 0) of the staircase.
fn stairs(x: f32) -> f32 {
    if x < FIRST_RISER_X {
        0.0
    } else {
        STEP_H * (((x - FIRST_RISER_X) / STEP_D) as usize + 1).min(N_STEPS) as f32
    }
}

/// The robot's pose for the frame: level-ish, base 0.75 m above the ground.
fn robot_frame() -> RobotFrame {
    RobotFrame::new(&MountPose::G1_MID360_DEFAULT, 0.01, -0.02, 0.75)
}

/// ~20,000 returns in the sensor frame: treads and ground (denser near the robot), risers, a few
/// off the robot's own legs and far walls; 2 mm noise.
fn staircase_cloud(rf: &RobotFrame) -> Vec<LidarPoint> {
    let mut rng = Rng(0x0057_A125);
    (0..N_POINTS)
        .map(|i| {
            let robot = match i % 25 {
                0 => [0.12 * rng.signed(), 0.15 * rng.signed(), 0.1 + 0.4 * rng.unit()], // own legs
                1 => [3.5 + rng.unit(), 4.0 * rng.signed(), 2.0 * rng.unit()],           // far wall
                2..=4 => {
                    // Risers: the vertical faces the sensor sees.
                    let k = (rng.next_u64() % N_STEPS as u64) as f32;
                    let x = FIRST_RISER_X + k * STEP_D;
                    [
                        x + noise(&mut rng, 0.002),
                        1.5 * rng.signed(),
                        STEP_H * (k + rng.unit()),
                    ]
                }
                _ => {
                    // Ground and treads, density falling off with range like a scanning lidar.
                    let r = 0.3 + 2.4 * rng.unit() * rng.unit().sqrt();
                    let theta = std::f32::consts::PI * rng.signed();
                    let (x, y) = (r * theta.cos(), r * theta.sin());
                    [x, y, stairs(x) + noise(&mut rng, 0.002)]
                }
            };
            // Back into the sensor frame: p_s = Rᵀ (p − t).
            let d = [robot[0] - rf.trans[0], robot[1] - rf.trans[1], robot[2] - rf.trans[2]];
            let xyz = core::array::from_fn(|k| rf.rot[0][k] * d[0] + rf.rot[1][k] * d[1] + rf.rot[2][k] * d[2]);
            LidarPoint {
                xyz,
                reflectivity: 40,
                tag: 0,
                offset_ns: i as u32 * sensor_io::livox::MID360_POINT_PERIOD_NS,
            }
        })
        .collect()
}

// ---------------------------------------------------------------------------------------------
// Timing.

struct Figures {
    median_us: f64,
    p99_us: f64,
    min_us: f64,
    mean_us: f64,
}

fn figures(mut times: Vec<f64>, mean_us: f64) -> Figures {
    times.sort_by(f64::total_cmp);
    Figures {
        median_us: percentile(&times, 0.5),
        p99_us: percentile(&times, 0.99),
        min_us: times[0],
        mean_us,
    }
}

/// Times `f` `iters` times individually after `warmup` calls, then once more as an untimed loop
/// for the mean.
fn time(warmup: usize, iters: usize, mut f: impl FnMut(usize)) -> Figures {
    for i in 0..warmup {
        f(i);
    }
    let times: Vec<f64> = (0..iters)
        .map(|i| {
            let t0 = Instant::now();
            f(i);
            t0.elapsed().as_secs_f64() * 1e6
        })
        .collect();
    let t0 = Instant::now();
    for i in 0..iters {
        f(i);
    }
    let mean = t0.elapsed().as_secs_f64() * 1e6 / iters as f64;
    figures(times, mean)
}

/// Times `f` `iters` times, each right after writing all of `evictor` (untimed), so `f` finds
/// nothing of its own in any cache level.
fn time_cold(iters: usize, evictor: &mut [u64], mut f: impl FnMut()) -> Figures {
    let mut total = 0.0;
    let times: Vec<f64> = (0..iters)
        .map(|i| {
            for (j, w) in evictor.iter_mut().enumerate().step_by(8) {
                *w = w.wrapping_add((i ^ j) as u64);
            }
            black_box(&evictor);
            let t0 = Instant::now();
            f();
            let us = t0.elapsed().as_secs_f64() * 1e6;
            total += us;
            us
        })
        .collect();
    figures(times, total / iters as f64)
}

fn show(name: &str, f: &Figures) {
    println!(
        "{name:<34} median {:>8.1} us  p99 {:>8.1} us  min {:>8.1} us  mean {:>8.1} us",
        f.median_us, f.p99_us, f.min_us, f.mean_us
    );
}

// ---------------------------------------------------------------------------------------------
// ORT baseline.

/// Writes the description (JSON), the weights if needed and the reference pair into a temp
/// folder and runs the ORT script; `None` (after saying why, loudly) if it cannot.
fn time_ort(model: &CnnModel, input: &[f32], output: &[f32]) -> Option<serde_json::Value> {
    let python = common::venv_python()?;
    let dir = std::env::temp_dir().join(format!("perception_frame_bench_{}", std::process::id()));
    let prepared = (|| -> Result<(PathBuf, PathBuf, PathBuf), String> {
        std::fs::create_dir_all(&dir).map_err(|e| e.to_string())?;
        let weights = model.weights_file(&dir).map_err(|e| e.to_string())?;
        let desc = dir.join("desc.json");
        std::fs::write(&desc, serde_json::to_string(&model.desc).map_err(|e| e.to_string())?)
            .map_err(|e| e.to_string())?;
        let mut in_shape = vec![1];
        in_shape.extend(model.desc.input_shape.clone().unwrap_or(vec![model.desc.input]));
        let (xb, yb): (Vec<u8>, Vec<u8>) = (
            input.iter().flat_map(|v| v.to_le_bytes()).collect(),
            output.iter().flat_map(|v| v.to_le_bytes()).collect(),
        );
        let views = vec![
            (
                "input",
                TensorView::new(Dtype::F32, in_shape, &xb).map_err(|e| e.to_string())?,
            ),
            (
                "output",
                TensorView::new(Dtype::F32, vec![1, output.len()], &yb).map_err(|e| e.to_string())?,
            ),
        ];
        let reference = dir.join("reference.safetensors");
        std::fs::write(
            &reference,
            safetensors::serialize(views, &None).map_err(|e| e.to_string())?,
        )
        .map_err(|e| e.to_string())?;
        Ok((weights, desc, reference))
    })();
    let (weights, desc, reference) = match prepared {
        Ok(p) => p,
        Err(e) => {
            loud(&format!(
                "NO ORT BASELINE: cannot write its inputs to {}: {e}",
                dir.display()
            ));
            return None;
        }
    };
    let args = [
        OsStr::new("--weights"),
        weights.as_os_str(),
        OsStr::new("--desc"),
        desc.as_os_str(),
        OsStr::new("--ref"),
        reference.as_os_str(),
    ];
    let result = common::run_ort_script(&python, "ort_terrain_cnn.py", args);
    let _ = std::fs::remove_dir_all(&dir);
    result
}

fn main() {
    let weights_dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("weights");
    let model = match CnnModel::from_files(
        &weights_dir.join("terrain_cnn.toml"),
        &weights_dir.join("terrain_cnn.safetensors"),
    ) {
        Some(Ok(m)) => m,
        Some(Err(e)) => panic!("terrain CNN files present but unreadable: {e}"),
        None => {
            loud(&format!(
                "NO TRAINED TERRAIN CNN: {}/terrain_cnn.{{toml,safetensors}} not found.\n\
                 Benchmarking the paper's architecture with RANDOM weights (timing is the same;\n\
                 the decoded token below is meaningless).",
                weights_dir.display()
            ));
            CnnModel::random(0x007E_44A1)
        }
    };
    let mut net = model.network();
    let n_out = net.output_dim();
    assert_eq!(net.input_dim(), BEV_LEN, "the terrain CNN must take the 6x60x60 BEV");

    // The frame: packets as the sensor sends them (a few frames, cycled, so frame and UDP
    // counters advance as in a stream).
    let rf = robot_frame();
    let filter = SelfFilter::G1_DEFAULT;
    let cloud = staircase_cloud(&rf);
    let mut writer = PacketWriter::new();
    let mut buf = vec![0u8; writer.max_packet_len()];
    let frames: Vec<Vec<Vec<u8>>> = (0..4u64)
        .map(|k| {
            let mut packets = Vec::new();
            writer
                .write_frame(&cloud, 1_000_000_000 + k * 100_000_000, &mut buf, |p| {
                    packets.push(p.to_vec())
                })
                .expect("encode");
            packets
        })
        .collect();
    let bytes: usize = frames[0].iter().map(Vec::len).sum();

    let mut asm = FrameAssembler::<LIDAR_FRAME_CAP>::new_boxed();
    let mut builder = BevBuilder::new_boxed();
    let mut grid = Box::new(BevGrid::zeroed());
    for p in &frames[0] {
        asm.push(p).expect("valid packet");
    }
    let points: Vec<LidarPoint> = asm.flush().expect("a frame").as_slice().to_vec();
    let stats = builder.build(&points, &rf, &filter, &mut grid);
    let occupied = (0..BEV_CELLS * BEV_CELLS)
        .filter(|&i| grid.data[CH_DENSITY * BEV_CELLS * BEV_CELLS + i] > 0.0)
        .count();
    let bev: Vec<f32> = grid.data.to_vec();
    let mut out = vec![0.0f32; n_out];
    net.step(&bev, &mut out).expect("step");
    let token = decode(&out, 0.0);

    println!("network: {} ({} params)", model.origin, net.param_count());
    println!(
        "shapes: {:?} -> {}",
        net.input_shape(),
        (0..model.desc.layers.len())
            .filter_map(|i| net.layer_output_shape(i).map(|s| format!("{s:?}")))
            .collect::<Vec<_>>()
            .join(" -> ")
    );
    println!(
        "frame: {} points, {} packets, {bytes} bytes; {} points kept, BEV: {} used, {} self hits, {} \
         outside, {occupied} cells occupied",
        cloud.len(),
        frames[0].len(),
        points.len(),
        stats.used,
        stats.self_hits,
        stats.outside
    );
    match token {
        Some(t) => println!(
            "output: {out:?} -> {:?}, h {:.3} m, d {:.3} m, yaw {:.1} deg (scene: stairs up, h 0.15 m, d 0.30 m, yaw 0)",
            t.class,
            t.step_height_m,
            t.step_depth_m,
            t.yaw_rad.to_degrees()
        ),
        None => println!("output: {out:?} -> no token (non-finite output)"),
    }

    // (a) The CNN alone.
    let cnn = time(CNN_WARMUP, CNN_ITERS, |_| {
        net.step(black_box(&bev), &mut out).expect("step");
        black_box(&out);
    });
    let cnn_portable = if has_avx2() {
        let mut portable = model.network();
        portable.use_portable_kernels();
        let mut y = vec![0.0f32; n_out];
        portable.step(&bev, &mut y).expect("step");
        assert_eq!(
            y.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
            out.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
            "portable and AVX2 kernels differ"
        );
        Some(time(CNN_WARMUP, CNN_ITERS, |_| {
            portable.step(black_box(&bev), &mut y).expect("step");
            black_box(&y);
        }))
    } else {
        None
    };

    // (a') The CNN as the firmware meets it: once per 10 Hz frame, after the simulator, the fast
    // group and everything else on the machine have had 100 ms to push its weights out of cache.
    // Evicted here by streaming a buffer larger than the last-level cache before each timed step.
    let mut evictor = vec![0u64; EVICT_BYTES / 8];
    let cnn_cold = time_cold(CNN_COLD_ITERS, &mut evictor, || {
        net.step(black_box(&bev), &mut out).expect("step");
        black_box(&out);
    });

    // (b) The whole frame, and its stages.
    let mut frame_once = |k: usize, out: &mut [f32]| -> Option<TerrainToken> {
        for p in &frames[k % frames.len()] {
            let _ = asm.push(black_box(p));
        }
        let points = asm.flush().map(|f| f.as_slice()).unwrap_or(&[]);
        builder.build(points, &rf, &filter, &mut grid);
        net.step(&grid.data, out).expect("step");
        decode(out, 0.0)
    };
    let full = time(FRAME_WARMUP, FRAME_ITERS, |k| {
        black_box(frame_once(k, &mut out));
    });
    let assemble = time(FRAME_WARMUP, FRAME_ITERS, |k| {
        for p in &frames[k % frames.len()] {
            let _ = asm.push(black_box(p));
        }
        black_box(asm.flush().map(|f| f.len));
    });
    let bev_build = time(FRAME_WARMUP, FRAME_ITERS, |_| {
        black_box(builder.build(black_box(&points), &rf, &filter, &mut grid));
    });

    println!();
    let isa = if cnn_portable.is_some() { "AVX2" } else { "portable" };
    show(&format!("(a) CNN step ({isa} kernels)"), &cnn);
    if let Some(p) = &cnn_portable {
        show("(a) CNN step (portable kernels)", p);
    }
    show("(a') CNN step, caches evicted first", &cnn_cold);
    println!(
        "    cold / warm = {:.2} (median); weights {:.2} MB",
        cnn_cold.median_us / cnn.median_us,
        net.param_count() as f64 * 4.0 / 1e6
    );
    show("(b) full frame", &full);
    show("    packets -> FrameAssembler", &assemble);
    show("    BevBuilder::build", &bev_build);
    println!("    (full frame = assemble + BEV + CNN + decode, measured together)");

    // (c) ORT.
    let Some(ort) = time_ort(&model, &bev, &out_of(&mut net, &bev, n_out)) else {
        println!("\nORT: unavailable (see above); only our figures reported");
        return;
    };
    let get = |which: &str, k: &str| ort[which][k].as_f64().unwrap_or(f64::NAN);
    println!(
        "\nORT {} (InferenceSession.run from Python, {} runs; max abs diff vs ours {:.2e}):",
        ort["ort_version"].as_str().unwrap_or("?"),
        ort["iters"],
        ort["ref_max_abs_err"].as_f64().unwrap_or(f64::NAN)
    );
    for (which, label) in [("single", "1 thread"), ("default", "ORT default threads")] {
        println!(
            "(c) ORT CNN, {label:<21}        median {:>8.1} us  p99 {:>8.1} us  min {:>8.1} us  mean {:>8.1} us",
            get(which, "median_us"),
            get(which, "p99_us"),
            get(which, "min_us"),
            get(which, "mean_us"),
        );
    }
    let (ort1, ortd) = (get("single", "median_us"), get("default", "median_us"));
    let verdict = |r: f64| if r <= 1.0 { "MET" } else { "NOT MET" };
    println!("\nratios (medians; target <= 1.0):");
    for (name, ours) in [("ours_cnn", cnn.median_us), ("ours_full_frame", full.median_us)] {
        println!(
            "  {name:<16}/ ORT_cnn(1 thread) = {:.3} ({})   / ORT_cnn(default) = {:.3} ({})",
            ours / ort1,
            verdict(ours / ort1),
            ours / ortd,
            verdict(ours / ortd)
        );
    }
    println!(
        "  by min: ours_cnn/ORT_cnn(1 thread) = {:.3}, ours_full_frame/ORT_cnn(1 thread) = {:.3}",
        cnn.min_us / get("single", "min_us"),
        full.min_us / get("single", "min_us")
    );
    println!(
        "RESULT {{\"ours_cnn_us\": {:.2}, \"ours_full_frame_us\": {:.2}, \"ort_cnn_1t_us\": {:.2}, \
         \"ort_cnn_default_us\": {:.2}, \"ratio_cnn\": {:.4}, \"ratio_full_frame\": {:.4}, \
         \"ours_cnn_min_us\": {:.2}, \"ours_full_frame_min_us\": {:.2}, \"ort_cnn_1t_min_us\": {:.2}, \
         \"ratio_cnn_min\": {:.4}, \"ratio_full_frame_min\": {:.4}}} (ratios against ORT 1 thread)",
        cnn.median_us,
        full.median_us,
        ort1,
        ortd,
        cnn.median_us / ort1,
        full.median_us / ort1,
        cnn.min_us,
        full.min_us,
        get("single", "min_us"),
        cnn.min_us / get("single", "min_us"),
        full.min_us / get("single", "min_us"),
    );
}

fn has_avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Our output on `x` (the reference the ORT graph must reproduce).
fn out_of(net: &mut Network, x: &[f32], n_out: usize) -> Vec<f32> {
    let mut y = vec![0.0f32; n_out];
    net.step(x, &mut y).expect("step");
    y
}
