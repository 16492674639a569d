//! The simulated MID-360 over the bridge: Livox datagrams each tick, decoded by the client into
//! 10 Hz frames; the terrain label rides on `Truth`.
mod common;

use std::time::Duration;

use g1_sim::lidar::LidarConfig;
use g1_sim::server::{serve_unix, ServeOptions};
use g1_sim::world::World;
use g1_sim::{ModelChoice, SimConfig, Simulator};
use hal::{Lidar, LowLevel, PointFrame, TerrainClass, TimeBase};
use sim_hal::bridge::{BridgeHal, Wants, LIDAR_FRAME_CAP};

type Server = std::thread::JoinHandle<Result<g1_sim::server::SessionSummary, g1_sim::server::ServeError>>;

/// Serves `sim` on a fresh Unix socket in a thread.
fn serve_in_thread(tag: &str, mut sim: Simulator) -> (std::path::PathBuf, Server) {
    let path = std::env::temp_dir().join(format!("g1-{tag}-{}.sock", std::process::id()));
    let p2 = path.clone();
    let opts = ServeOptions {
        quiet: true,
        ..ServeOptions::default()
    };
    (
        path,
        std::thread::spawn(move || serve_unix(&p2, &mut sim, &opts, || {})),
    )
}

#[test]
fn lidar_frames_and_terrain_truth_cross_the_bridge() {
    common::require_deps();
    let world = World::preset("stairs-up").unwrap();
    let mut sim = Simulator::load_in(ModelChoice::G1_29Dof, SimConfig::default(), Some(&world)).unwrap();
    sim.attach_lidar(LidarConfig::default()).unwrap();
    let hold = sim.hold_initial_pose_command();
    let (path, server) = serve_in_thread("lidar-bridge", sim);
    let want = Wants {
        truth: true,
        lidar: true,
    };
    let mut hal = BridgeHal::connect_unix(&path, want, Duration::from_secs(20), || Ok(())).unwrap();
    let mut frame = Box::<PointFrame<LIDAR_FRAME_CAP>>::default();
    let mut frames = Vec::new();
    let mut state = hal::LowState::default();
    // 0.45 s at 500 Hz: frames complete at 0.1, 0.2, 0.3, 0.4 s (when the next one starts).
    for k in 0..225u64 {
        let t = hal.wait_tick().unwrap();
        assert_eq!(t.index, k);
        hal.read_state(&mut state).unwrap();
        if hal.read_frame(&mut frame).unwrap() {
            frames.push((k, frame.len, frame.timestamp_ns, frame.overflow));
        }
        let z = hal.truth().terrain.expect("terrain truth in a world");
        assert_eq!(z.class, TerrainClass::StairsUp);
        assert!((z.step_height_m - 0.15).abs() < 1e-6);
        if k < 224 {
            hal.write_command(&hold).unwrap();
        }
    }
    let counters = hal.lidar_counters().unwrap();
    hal.close();
    server.join().unwrap().unwrap();
    println!("frames (tick, points, t0, overflow): {frames:?}\n{counters:?}");
    assert_eq!(frames.len(), 4, "{frames:?}");
    for (i, (_, n, t0, overflow)) in frames.iter().enumerate() {
        assert_eq!(*t0, i as u64 * 100_000_000, "frames start on the 100 ms grid");
        // 20,000 rays per frame; dropouts (1 %), sky and sub-0.1 m returns are dropped.
        assert!((12_000..=20_000).contains(n), "frame {i}: {n} points");
        assert_eq!(*overflow, 0);
    }
    assert_eq!(counters.decoder.malformed.total(), 0);
    assert_eq!(counters.decoder.lost_packets, 0);
    assert_eq!(counters.framing_errors, 0);
    assert!(
        counters.decoder.near_dropped > 0,
        "dropouts arrive as zero points and are dropped"
    );
}

#[test]
fn asking_for_lidar_without_one_is_refused_clearly() {
    common::require_deps();
    let sim = Simulator::load(ModelChoice::G1_29Dof, SimConfig::default()).unwrap();
    let (path, server) = serve_in_thread("nolidar", sim);
    let want = Wants {
        truth: false,
        lidar: true,
    };
    let err = BridgeHal::connect_unix(&path, want, Duration::from_secs(20), || Ok(()))
        .err()
        .expect("refused");
    assert!(err.to_string().contains("--lidar"), "{err}");
    assert!(server.join().unwrap().is_err());
}
