//! The terrain CNN built into the firmware: it matches what `g1-train` computed for the same grids
//! (parity fixture written at export), loads only sane networks, and fails safe on bad input.
use control::terrain_net::{TerrainNet, TerrainNetError, EMBEDDED_DESC, EMBEDDED_WEIGHTS};
use safetensors::SafeTensors;
use sensor_io::bev::BevGrid;

const PARITY: &[u8] = include_bytes!("../weights/terrain_cnn_parity.safetensors");

fn f32s(b: &[u8]) -> Vec<f32> {
    b.chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect()
}

#[test]
fn embedded_network_matches_the_trainer_to_1e_4() {
    let st = SafeTensors::deserialize(PARITY).unwrap();
    let grids = f32s(st.tensor("bev").unwrap().data());
    let want = f32s(st.tensor("outputs").unwrap().data());
    let n = want.len() / 7;
    assert!(n >= 3, "fixture holds {n} grids");
    let mut net = TerrainNet::embedded().unwrap();
    // The fixture belongs to these weights (re-export both together).
    let (_, meta) = SafeTensors::read_metadata(PARITY).unwrap();
    let sha = meta.metadata().as_ref().unwrap()["weights_sha256"].clone();
    assert_eq!(net.weights_sha256(), sha, "parity fixture was made for other weights");
    let mut grid = Box::new(BevGrid::zeroed());
    let mut worst = 0.0f32;
    for k in 0..n {
        grid.data.copy_from_slice(&grids[k * 21600..(k + 1) * 21600]);
        assert!(net.estimate(&grid, 0.0).is_some());
        for (a, b) in net.outputs().iter().zip(&want[k * 7..(k + 1) * 7]) {
            worst = worst.max((a - b).abs());
        }
    }
    assert!(worst <= 1e-4, "max |firmware - trainer| = {worst}");
}

#[test]
fn a_non_finite_grid_gives_no_token_and_the_net_recovers() {
    let mut net = TerrainNet::embedded().unwrap();
    let mut grid = Box::new(BevGrid::zeroed());
    grid.data[1234] = f32::NAN;
    assert!(net.estimate(&grid, 0.3).is_none());
    grid.data[1234] = 0.0;
    let t = net.estimate(&grid, 0.3).expect("finite grid, finite token");
    assert!(t.is_finite());
}

#[test]
fn wrong_networks_are_refused_with_a_reason() {
    let dir = std::env::temp_dir().join(format!("g1fw-terrain-net-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let w = dir.join("w.safetensors");
    std::fs::write(&w, EMBEDDED_WEIGHTS).unwrap();
    // Drop the head: the output is 128 wide, not 7.
    let cut = EMBEDDED_DESC.rfind("[[layers]]").unwrap();
    let d = dir.join("short.toml");
    std::fs::write(&d, &EMBEDDED_DESC[..cut]).unwrap();
    let e = TerrainNet::load(&d, &w).err().expect("must fail");
    assert!(matches!(e, TerrainNetError::Shape { output: 128, .. }), "{e}");
    std::fs::write(&d, "input = [").unwrap();
    let e = TerrainNet::load(&d, &w).err().expect("must fail");
    assert!(e.to_string().contains("short.toml"), "{e}");
    let e = TerrainNet::load(&dir.join("missing.toml"), &w)
        .err()
        .expect("must fail");
    assert!(e.to_string().contains("missing.toml"), "{e}");
    std::fs::remove_dir_all(&dir).ok();
}
