//! `Network::step` must not allocate: counts allocations on this thread around a step loop.
// Test inputs come from std's math on the host; this never runs on the robot.
#![allow(clippy::disallowed_methods)]

use control::nn::{LayerDesc, Network, NetworkDesc};
use safetensors::tensor::{Dtype, TensorView};
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

thread_local! {
    static ALLOCS: Cell<usize> = const { Cell::new(0) };
}

/// Counts allocations per thread (so parallel tests do not interfere) and defers to `System`.
struct Counting;

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        ALLOCS.with(|c| c.set(c.get() + 1));
        // SAFETY: forwarded unchanged to the system allocator.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: forwarded unchanged to the system allocator.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        ALLOCS.with(|c| c.set(c.get() + 1));
        // SAFETY: forwarded unchanged to the system allocator.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn step_does_not_allocate() {
    let tensors: Vec<(&str, Vec<usize>)> = vec![
        ("w_ih", vec![32, 5]),
        ("w_hh", vec![32, 8]),
        ("b_ih", vec![32]),
        ("b_hh", vec![32]),
        ("l.w", vec![4, 8]),
        ("l.b", vec![4]),
    ];
    let data: Vec<Vec<u8>> = tensors
        .iter()
        .map(|(_, s)| {
            let n: usize = s.iter().product();
            (0..n)
                .flat_map(|i| ((i % 7) as f32 * 0.1 - 0.3).to_le_bytes())
                .collect()
        })
        .collect();
    let views: Vec<(&str, TensorView<'_>)> = tensors
        .iter()
        .zip(&data)
        .map(|((n, s), d)| (*n, TensorView::new(Dtype::F32, s.clone(), d).unwrap()))
        .collect();
    let bytes = safetensors::serialize(views, &None).unwrap();
    let desc = NetworkDesc {
        input: 5,
        input_shape: None,
        layers: vec![
            LayerDesc::Lstm {
                weight_ih: "w_ih".into(),
                weight_hh: "w_hh".into(),
                bias_ih: "b_ih".into(),
                bias_hh: "b_hh".into(),
                initial_hidden: None,
                initial_cell: None,
            },
            LayerDesc::Tanh,
            LayerDesc::Linear {
                weight: "l.w".into(),
                bias: "l.b".into(),
            },
            LayerDesc::Elu { alpha: 1.0 },
            LayerDesc::Relu,
        ],
    };
    let mut net = Network::from_safetensors_bytes(&desc, &bytes).unwrap();
    let x = [0.5f32; 5];
    let mut y = [0.0f32; 4];
    let before = ALLOCS.with(Cell::get);
    for _ in 0..1000 {
        net.step(&x, &mut y).unwrap();
    }
    net.reset();
    net.step(&x, &mut y).unwrap();
    let after = ALLOCS.with(Cell::get);
    assert_eq!(after - before, 0, "step/reset allocated {} times", after - before);
}

#[test]
fn conv_step_does_not_allocate() {
    // A small terrain-CNN-shaped net: conv (stride 2, padding 1) -> relu -> conv -> relu -> linear.
    let tensors: Vec<(&str, Vec<usize>)> = vec![
        ("c1.w", vec![10, 3, 3, 3]),
        ("c1.b", vec![10]),
        ("c2.w", vec![17, 10, 3, 3]),
        ("c2.b", vec![17]),
        ("l.w", vec![5, 17 * 4 * 4]),
        ("l.b", vec![5]),
    ];
    let data: Vec<Vec<u8>> = tensors
        .iter()
        .map(|(_, s)| {
            let n: usize = s.iter().product();
            (0..n)
                .flat_map(|i| ((i % 11) as f32 * 0.05 - 0.25).to_le_bytes())
                .collect()
        })
        .collect();
    let views: Vec<(&str, TensorView<'_>)> = tensors
        .iter()
        .zip(&data)
        .map(|((n, s), d)| (*n, TensorView::new(Dtype::F32, s.clone(), d).unwrap()))
        .collect();
    let bytes = safetensors::serialize(views, &None).unwrap();
    let conv = |w: &str, b: &str, stride| LayerDesc::Conv2d {
        weight: w.into(),
        bias: b.into(),
        stride,
        padding: 1,
    };
    let desc = NetworkDesc {
        input: 3 * 15 * 15,
        input_shape: Some(vec![3, 15, 15]),
        layers: vec![
            conv("c1.w", "c1.b", 2),
            LayerDesc::Relu,
            conv("c2.w", "c2.b", 2),
            LayerDesc::Relu,
            LayerDesc::Linear {
                weight: "l.w".into(),
                bias: "l.b".into(),
            },
        ],
    };
    let mut net = Network::from_safetensors_bytes(&desc, &bytes).unwrap();
    let x: Vec<f32> = (0..3 * 15 * 15).map(|i| (i as f32 * 0.37).sin()).collect();
    let mut y = [0.0f32; 5];
    let before = ALLOCS.with(Cell::get);
    for _ in 0..200 {
        net.step(&x, &mut y).unwrap();
    }
    let after = ALLOCS.with(Cell::get);
    assert_eq!(after - before, 0, "conv step allocated {} times", after - before);
    assert!(y.iter().all(|v| v.is_finite()));
}

/// The mirror-averaged policy (`[policy] mirror = "average"`) steps its twin from buffers made once.
#[test]
fn a_mirror_averaged_actor_step_does_not_allocate() {
    use control::spec::{DeploySpec, MirrorMode};
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../specs/stairs/g1_stairs_lstm.toml");
    let mut spec = DeploySpec::load(&path).unwrap();
    spec.policy.mirror = MirrorMode::Average;
    let net = Network::load(&spec.policy.network, &spec.weights_path()).unwrap();
    let mut actor = control::actor::Actor::new(&spec, net).unwrap();
    let obs: Vec<f32> = (0..spec.observation_dim()).map(|i| (i % 5) as f32 * 0.1).collect();
    let mut act = vec![0.0; spec.num_joints()];
    actor.step(&obs, &mut act).unwrap();
    let before = ALLOCS.with(Cell::get);
    for _ in 0..100 {
        actor.step(&obs, &mut act).unwrap();
    }
    actor.reset();
    let after = ALLOCS.with(Cell::get);
    assert_eq!(after, before, "allocations during 100 averaged steps");
}
