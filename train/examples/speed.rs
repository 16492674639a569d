use candle_core::{DType, Device, Tensor};
use candle_nn::{VarBuilder, VarMap};
use std::time::Instant;
fn main() -> anyhow::Result<()> {
    let dev = Device::Cpu;
    let vm = VarMap::new();
    let model = train::cnn::model::TerrainCnn::new(VarBuilder::from_varmap(&vm, DType::F32, &dev))?;
    let x = Tensor::randn(0f32, 1.0, (64, 6, 60, 60), &dev)?;
    for _ in 0..2 {
        let _ = model.forward_t(&x, true)?;
    }
    let t = Instant::now();
    for _ in 0..5 {
        let _ = model.forward_t(&x, true)?.sum_all()?.to_scalar::<f32>()?;
    }
    println!("forward {:.1} ms/batch", t.elapsed().as_secs_f64() * 200.0);
    let t = Instant::now();
    for _ in 0..5 {
        let l = model.forward_t(&x, true)?.sum_all()?;
        let _g = l.backward()?;
    }
    println!("fwd+bwd {:.1} ms/batch", t.elapsed().as_secs_f64() * 200.0);
    Ok(())
}
