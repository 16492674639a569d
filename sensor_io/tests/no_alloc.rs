//! The per-frame paths allocate nothing once constructed: `BevBuilder::build*` and
//! `FrameAssembler::push`/`flush`. A counting global allocator counts this thread's allocations
//! only, so tests running in parallel do not disturb each other.
// Test inputs come from std's math on the host; this never runs on the robot.
#![allow(clippy::disallowed_methods)]
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

use hal::LidarPoint;
use sensor_io::bev::*;
use sensor_io::livox::*;

struct Counting;

thread_local! {
    static ALLOCS: Cell<u64> = const { Cell::new(0) };
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let _ = ALLOCS.try_with(|c| c.set(c.get() + 1));
        System.alloc(layout)
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        System.dealloc(ptr, layout)
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let _ = ALLOCS.try_with(|c| c.set(c.get() + 1));
        System.realloc(ptr, layout, new_size)
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

fn allocations<R>(f: impl FnOnce() -> R) -> (u64, R) {
    let before = ALLOCS.with(|c| c.get());
    let r = f();
    (ALLOCS.with(|c| c.get()) - before, r)
}

fn cloud(n: usize) -> Vec<LidarPoint> {
    (0..n)
        .map(|i| {
            let a = i as f32 * 0.01;
            LidarPoint {
                xyz: [
                    (1.0 + (i % 7) as f32 * 0.3) * a.cos(),
                    (1.0 + (i % 7) as f32 * 0.3) * a.sin(),
                    -0.7,
                ],
                reflectivity: 10,
                tag: 0,
                offset_ns: 0,
            }
        })
        .collect()
}

#[test]
fn bev_build_does_not_allocate() {
    let points = cloud(20_000);
    let robot: Vec<[f32; 3]> = points.iter().map(|p| p.xyz).collect();
    let mut b = BevBuilder::new_boxed();
    let mut out = Box::new(BevGrid::zeroed());
    let frame = RobotFrame::new(&MountPose::G1_MID360_DEFAULT, 0.02, -0.03, 0.75);
    let (n, s) = allocations(|| b.build(&points, &frame, &SelfFilter::G1_DEFAULT, &mut out));
    assert_eq!(n, 0);
    assert!(s.used > 0);
    let (n, s) = allocations(|| b.build_robot_points(&robot, &mut out));
    assert_eq!(n, 0);
    assert!(s.used > 0);
    // The counter does count (so the zeros above mean something).
    let (n, _) = allocations(|| vec![0u8; 10]);
    assert_eq!(n, 1);
}

#[test]
fn frame_assembly_does_not_allocate() {
    let points = cloud(5_000);
    let mut packets = Vec::new();
    let mut w = PacketWriter::new();
    let mut buf = vec![0u8; w.max_packet_len()];
    for frame in 0..3 {
        w.write_frame(&points, frame * 100_000_000, &mut buf, |p| packets.push(p.to_vec()))
            .unwrap();
    }
    let mut bad = packets[5].clone();
    bad[40] ^= 1;
    let mut asm = FrameAssembler::<4096>::new_boxed();
    let (n, frames) = allocations(|| {
        let mut frames = 0;
        for p in &packets {
            if let Ok(Some(f)) = asm.push(p) {
                assert_eq!((f.len, f.overflow), (4096, 5_000 - 4096));
                frames += 1;
            }
            assert!(asm.push(&bad).is_err());
        }
        frames + asm.flush().is_some() as usize
    });
    assert_eq!(n, 0);
    assert_eq!(frames, 3);
}
