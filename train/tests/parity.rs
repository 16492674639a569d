//! Training and firmware compute the same numbers: a model with random weights and random
//! BatchNorm statistics, run by candle (eval mode), against its BatchNorm-folded export run by the
//! firmware's executor, on real BEV grids (the committed parity fixture's). ≤ 1e-4.
use candle_core::{DType, Device, Tensor};
use candle_nn::{VarBuilder, VarMap};
use control::nn::Network;
use safetensors::SafeTensors;
use train::cnn::data::GRID;
use train::cnn::model::TerrainCnn;

const FIXTURE: &[u8] = include_bytes!("../../control/weights/terrain_cnn_parity.safetensors");

/// A tensor of the parity fixture, as f32 values.
fn fixture_f32s(name: &str) -> Vec<f32> {
    let st = SafeTensors::deserialize(FIXTURE).unwrap();
    train::tensor_file::f32_values(&st.tensor(name).unwrap()).unwrap()
}

#[test]
fn candle_and_the_firmware_executor_agree_to_1e_4() {
    let dev = Device::Cpu;
    let vm = VarMap::new();
    let model = TerrainCnn::new(VarBuilder::from_varmap(&vm, DType::F32, &dev)).unwrap();
    train::cnn::fit::seeded_init(&vm, 7, &dev).unwrap();
    // Non-trivial BatchNorm: scale, shift and running statistics away from 1 / 0.
    let mut rng = labkit::rng::Rng(99);
    {
        let data = vm.data().lock().unwrap();
        let mut names: Vec<&String> = data.keys().filter(|n| n.starts_with("bn")).collect();
        names.sort();
        for name in names {
            let v = &data[name];
            let (lo, hi) = if name.ends_with("running_var") || name.ends_with("weight") {
                (0.5, 2.0)
            } else {
                (-0.3, 0.3)
            };
            let vals: Vec<f32> = (0..v.elem_count()).map(|_| rng.range(lo, hi) as f32).collect();
            v.set(&Tensor::from_vec(vals, v.dims(), &dev).unwrap()).unwrap();
        }
    }
    let grids = fixture_f32s("bev");
    let n = grids.len() / GRID;
    let x = Tensor::from_vec(grids.clone(), (n, 6, 60, 60), &dev).unwrap();
    let want = model.forward_t(&x, false).unwrap().to_vec2::<f32>().unwrap();

    let exported = train::cnn::export::fold(&vm).unwrap();
    let bytes = exported.safetensors_bytes(&Default::default()).unwrap();
    let desc: control::nn::NetworkDesc = toml::from_str(&exported.desc_toml().unwrap()).unwrap();
    let mut net = Network::from_safetensors_bytes(&desc, &bytes).unwrap();
    let mut out = [0.0f32; 7];
    let mut worst = 0.0f32;
    for k in 0..n {
        net.step(&grids[k * GRID..(k + 1) * GRID], &mut out).unwrap();
        for (a, b) in out.iter().zip(&want[k]) {
            worst = worst.max((a - b).abs());
        }
    }
    // Outputs are O(1..100) (cm, degree-scaled yaw vector): 1e-4 absolute is tight.
    assert!(worst <= 1e-4, "max |firmware - candle| = {worst}");
    assert!(
        want.iter().flatten().any(|v| v.abs() > 0.1),
        "outputs must not be trivially zero"
    );
}

/// A fine-tune starts from the committed export itself: `fit --init <export> --freeze-bn` unfolds
/// it, and that network (BatchNorm in inference mode) computes the fixture's outputs, and folds
/// back to the committed tensors bit for bit.
#[test]
fn the_committed_export_unfolds_into_a_network_that_computes_it() {
    let dev = Device::Cpu;
    let dir = std::env::temp_dir().join(format!("g1-unfold-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let export = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../control/weights/terrain_cnn.safetensors");
    assert!(train::cnn::export::is_export(&export).unwrap());
    let vm = VarMap::new();
    let model = TerrainCnn::new(VarBuilder::from_varmap(&vm, DType::F32, &dev)).unwrap();
    train::cnn::fit::load_init(&vm, &export, &dev).unwrap();

    let grids = fixture_f32s("bev");
    let want = fixture_f32s("outputs");
    let n = grids.len() / GRID;
    let x = Tensor::from_vec(grids, (n, 6, 60, 60), &dev).unwrap();
    let got = model
        .forward_t(&x, false)
        .unwrap()
        .flatten_all()
        .unwrap()
        .to_vec1::<f32>()
        .unwrap();
    let worst = got.iter().zip(&want).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
    assert!(worst <= 1e-4, "unfolded network off the fixture by {worst}");

    // Folding again gives the committed tensors exactly.
    let again = train::cnn::export::fold(&vm).unwrap();
    let committed = std::fs::read(&export).unwrap();
    let committed = SafeTensors::deserialize(&committed).unwrap();
    for (name, (shape, data)) in &again.tensors {
        let t = committed.tensor(name).unwrap();
        assert_eq!(t.shape(), shape.as_slice(), "{name}");
        let bytes: Vec<u8> = data.iter().flat_map(|v| v.to_le_bytes()).collect();
        assert!(bytes == t.data(), "{name} changed in the round trip");
    }
    // A checkpoint is not an export.
    let ckpt = dir.join("checkpoint.safetensors");
    vm.save(&ckpt).unwrap();
    assert!(!train::cnn::export::is_export(&ckpt).unwrap());
    let _ = std::fs::remove_dir_all(&dir);
}
