//! The UDP lidar HAL against the assembler it wraps: the same datagrams give the same frames over
//! loopback; datagrams from another address, malformed ones and oversized ones are counted, never
//! a panic; a taken port is a clear error.
use std::net::{IpAddr, Ipv4Addr, SocketAddr, UdpSocket};

use hal::{Lidar, LidarPoint, PointFrame, XorShift64};
use robot_io::{UdpLidar, UdpLidarConfig};
use sensor_io::livox::{boxed_point_frame, FrameAssembler, PacketWriter};

const CAP: usize = 4096;
const LOOPBACK: IpAddr = IpAddr::V4(Ipv4Addr::LOCALHOST);

/// `frames` frames of pseudo-random points, as the MID-360 would packetise them.
fn datagrams(frames: usize, points_per_frame: usize) -> Vec<Vec<u8>> {
    let mut rng = XorShift64(7);
    let mut writer = PacketWriter::new();
    let mut buf = vec![0u8; writer.max_packet_len()];
    let mut out = Vec::new();
    for f in 0..frames {
        let points: Vec<LidarPoint> = (0..points_per_frame)
            .map(|_| LidarPoint {
                xyz: [rng.range(0.5, 8.0), rng.range(-4.0, 4.0), rng.range(-1.5, 1.5)],
                reflectivity: (rng.below(256)) as u8,
                tag: 0,
                offset_ns: 0,
            })
            .collect();
        writer
            .write_frame(&points, 1_000_000_000 + f as u64 * 100_000_000, &mut buf, |d| {
                out.push(d.to_vec())
            })
            .unwrap();
    }
    out
}

fn open(lidar: Option<IpAddr>) -> UdpLidar<CAP> {
    UdpLidar::open(UdpLidarConfig {
        bind: SocketAddr::new(LOOPBACK, 0),
        lidar,
        ..UdpLidarConfig::default()
    })
    .expect("bind a loopback port")
}

/// Sends `d` and waits until the receiver has taken it (loopback delivers on send; the wait only
/// guards against a slow scheduler).
fn send_and_take(tx: &UdpSocket, rx: &mut UdpLidar<CAP>, d: &[u8]) {
    tx.send(d).unwrap();
    let before = rx.counters().datagrams;
    for _ in 0..100_000 {
        rx.poll().unwrap();
        if rx.counters().datagrams > before {
            return;
        }
        std::thread::yield_now();
    }
    panic!("datagram not received over loopback");
}

#[test]
fn loopback_datagrams_give_the_assemblers_frames() {
    let packets = datagrams(4, 1000);
    let mut rx = open(Some(LOOPBACK));
    let tx = UdpSocket::bind((LOOPBACK, 0)).unwrap();
    tx.connect(rx.local_addr()).unwrap();

    let mut direct = FrameAssembler::<CAP>::new_boxed();
    let mut want: Vec<Box<PointFrame<CAP>>> = Vec::new();
    let mut got: Vec<Box<PointFrame<CAP>>> = Vec::new();
    let mut out = boxed_point_frame::<CAP>();
    for d in &packets {
        if let Some(f) = direct.push(d).unwrap() {
            let mut copy = boxed_point_frame::<CAP>();
            copy.copy_from(f);
            want.push(copy);
        }
        send_and_take(&tx, &mut rx, d);
        if rx.read_frame(&mut out).unwrap() {
            let mut copy = boxed_point_frame::<CAP>();
            copy.copy_from(&out);
            got.push(copy);
        }
    }
    // A frame completes when the next one starts: 4 frames sent, 3 complete.
    assert_eq!(want.len(), 3);
    assert_eq!(got.len(), want.len());
    for (a, b) in want.iter().zip(&got) {
        assert_eq!(a.len, 1000);
        assert_eq!((a.len, a.timestamp_ns, a.overflow), (b.len, b.timestamp_ns, b.overflow));
        assert_eq!(a.as_slice(), b.as_slice());
    }
    assert!(!rx.read_frame(&mut out).unwrap(), "no new frame without new packets");
    let c = rx.counters();
    assert_eq!(
        (c.datagrams, c.foreign, c.malformed, c.frames),
        (packets.len() as u64, 0, 0, 3)
    );
}

#[test]
fn foreign_malformed_and_oversized_datagrams_are_counted_not_fatal() {
    let packets = datagrams(2, 300);
    // Only packets from 192.168.123.120 are accepted: everything from loopback is foreign.
    let mut strict = open(Some(robot_io::udp_lidar::DEFAULT_LIDAR_ADDR));
    let tx = UdpSocket::bind((LOOPBACK, 0)).unwrap();
    tx.connect(strict.local_addr()).unwrap();
    for d in &packets {
        send_and_take(&tx, &mut strict, d);
    }
    let mut out = boxed_point_frame::<CAP>();
    assert!(!strict.read_frame(&mut out).unwrap());
    assert_eq!(strict.counters().foreign, packets.len() as u64);
    assert_eq!(strict.counters().frames, 0);

    let mut rx = open(None);
    tx.connect(rx.local_addr()).unwrap();
    let mut bad_crc = packets[0].clone();
    let last = bad_crc.len() - 1;
    bad_crc[last] ^= 0xff;
    for d in [&b"hello"[..], &bad_crc[..], &vec![0x5a; 9000][..], &[][..]] {
        send_and_take(&tx, &mut rx, d);
    }
    assert_eq!(rx.counters().malformed, 4);
    // The good stream still assembles after the garbage.
    for d in &packets {
        send_and_take(&tx, &mut rx, d);
    }
    assert!(rx.read_frame(&mut out).unwrap());
    assert_eq!(out.len, 300);
}

#[test]
fn a_taken_port_is_a_clear_error() {
    let first = open(None);
    let err = UdpLidar::<CAP>::open(UdpLidarConfig {
        bind: first.local_addr(),
        lidar: None,
        ..UdpLidarConfig::default()
    })
    .err()
    .expect("second bind fails");
    let msg = err.to_string();
    assert!(
        msg.contains(&first.local_addr().to_string()) && msg.contains("another program"),
        "{msg}"
    );
}
