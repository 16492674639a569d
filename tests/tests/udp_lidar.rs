//! The MID-360 over UDP (`robot_io::UdpLidar`) against the simulator bridge's lidar path: the
//! simulated MID-360's own datagrams, sent over loopback as the real lidar would send them, give
//! the same frames and, through the firmware's perception step (BEV + terrain CNN), the same
//! terrain tokens, tick by tick.
use std::net::{IpAddr, Ipv4Addr, SocketAddr, UdpSocket};
use std::time::Duration;

use control::perception::Perception;
use control::spec::DeploySpec;
use hal::{Lidar, LowCommand, LowLevel, LowState, TimeBase};
use integration_tests::*;
use robot_io::{UdpLidar, UdpLidarConfig};
use sensor_io::livox::boxed_point_frame;
use sim_hal::bridge::{datagrams, SimLaunch, Wants, LIDAR_FRAME_CAP};

#[test]
fn udp_lidar_gives_the_bridge_paths_frames_and_tokens() {
    if shared_dir().is_none() {
        return skip_or_fail("udp_lidar_gives_the_bridge_paths_frames_and_tokens");
    }
    let launch = SimLaunch {
        bin: Some(built_bin("g1-sim")),
        world: Some("stairs-up".into()),
        ..SimLaunch::new("g1-12dof", 0.002)
    };
    let wants = Wants {
        truth: false,
        lidar: true,
    };
    let (sim, mut bridge) = launch
        .start("udp_lidar", wants, Duration::from_secs(60))
        .expect("start g1-sim with the MID-360");
    let loopback = IpAddr::V4(Ipv4Addr::LOCALHOST);
    let mut udp = UdpLidar::<LIDAR_FRAME_CAP>::open(UdpLidarConfig {
        bind: SocketAddr::new(loopback, 0),
        lidar: Some(loopback),
        ..UdpLidarConfig::default()
    })
    .expect("bind a loopback port");
    let tx = UdpSocket::bind((loopback, 0)).unwrap();
    tx.connect(udp.local_addr()).unwrap();

    let spec = DeploySpec::load(&repo_root().join("specs/stairs/g1_stairs_lstm.toml")).expect("stair spec");
    let mut via_bridge = Perception::new(&spec.perception, &spec.base_dir);
    let mut via_udp = Perception::new(&spec.perception, &spec.base_dir);
    let est = control::runtime::Estimate::default();
    let (mut frame_a, mut frame_b) = (
        boxed_point_frame::<LIDAR_FRAME_CAP>(),
        boxed_point_frame::<LIDAR_FRAME_CAP>(),
    );
    let mut state = LowState::default();
    let (mut frames, mut sent, mut stairs_tokens) = (0, 0u64, 0);
    // 0.45 s: four 10 Hz frames complete. Motors off: the robot sinks, the views change.
    for _ in 0..225 {
        let tick = bridge.wait_tick().expect("tick");
        bridge.read_state(&mut state).expect("state");
        for d in datagrams(bridge.lidar_datagrams()) {
            tx.send(d.expect("well-framed bridge payload")).unwrap();
            sent += 1;
        }
        // Loopback delivers on send; wait only for a slow scheduler.
        for _ in 0..100_000 {
            udp.poll().unwrap();
            if udp.counters().datagrams == sent {
                break;
            }
            std::thread::yield_now();
        }
        assert_eq!(udp.counters().datagrams, sent, "datagrams lost on loopback");
        let a = bridge.read_frame(&mut frame_a).expect("bridge frame");
        let b = udp.read_frame(&mut frame_b).expect("udp frame");
        assert_eq!(a, b, "a frame completed on one path only (tick {})", tick.index);
        if a {
            frames += 1;
            assert!(frame_a.len > 1000, "{} points", frame_a.len);
            assert_eq!((frame_a.len, frame_a.timestamp_ns), (frame_b.len, frame_b.timestamp_ns));
            assert_eq!(frame_a.as_slice(), frame_b.as_slice());
            via_bridge.frame_mut().copy_from(&frame_a);
            via_udp.frame_mut().copy_from(&frame_b);
            let ta = via_bridge.step(tick.time_ns, true, &est);
            let tb = via_udp.step(tick.time_ns, true, &est);
            assert_eq!(ta, tb);
            if ta.token.class != hal::TerrainClass::Flat {
                stairs_tokens += 1;
            }
        }
        bridge.write_command(&LowCommand::default()).expect("command");
    }
    assert!(frames >= 3, "{frames} frames");
    assert_eq!(udp.counters().malformed, 0);
    println!(
        "{frames} frames, {sent} datagrams, {stairs_tokens} tokens not flat; assembler {:?}",
        udp.assembler_stats()
    );
    bridge.close();
    drop(sim);
}
