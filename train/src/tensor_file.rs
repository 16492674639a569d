//! Writing safetensors files: named tensors in, bytes out. The actor export, the critic file, the
//! widened actor and the CNN export all write through here, so the layout (little-endian values,
//! the header's metadata) is decided once; [`f32_values`] reads an f32 tensor back.
use std::collections::HashMap;

use candle_core::Tensor;
use safetensors::tensor::{Dtype, TensorView};

/// One tensor of a file: its name, element type, shape and little-endian bytes.
#[derive(Clone, Debug, PartialEq)]
pub struct NamedTensor {
    pub name: String,
    pub dtype: Dtype,
    pub shape: Vec<usize>,
    pub bytes: Vec<u8>,
}

impl NamedTensor {
    pub fn f32(name: impl Into<String>, shape: Vec<usize>, values: &[f32]) -> Self {
        Self {
            name: name.into(),
            dtype: Dtype::F32,
            shape,
            bytes: values.iter().flat_map(|v| v.to_le_bytes()).collect(),
        }
    }

    pub fn f64(name: impl Into<String>, shape: Vec<usize>, values: &[f64]) -> Self {
        Self {
            name: name.into(),
            dtype: Dtype::F64,
            shape,
            bytes: values.iter().flat_map(|v| v.to_le_bytes()).collect(),
        }
    }

    /// A candle tensor's values as f32, in its own shape.
    pub fn from_candle(name: impl Into<String>, t: &Tensor) -> anyhow::Result<Self> {
        let values: Vec<f32> = t.flatten_all()?.to_vec1()?;
        Ok(Self::f32(name, t.dims().to_vec(), &values))
    }
}

/// The safetensors bytes of `tensors`, with `metadata` in the header when given. The file's order
/// is safetensors' own (by alignment, then name), whatever order `tensors` come in.
pub fn serialize(tensors: &[NamedTensor], metadata: Option<HashMap<String, String>>) -> anyhow::Result<Vec<u8>> {
    let views = tensors
        .iter()
        .map(|t| Ok((t.name.as_str(), TensorView::new(t.dtype, t.shape.clone(), &t.bytes)?)))
        .collect::<Result<Vec<_>, safetensors::SafeTensorError>>()
        .map_err(|e| anyhow::anyhow!("a tensor's bytes do not match its shape: {e:?}"))?;
    safetensors::serialize(views, &metadata).map_err(|e| anyhow::anyhow!("{e:?}"))
}

/// An f32 tensor's values; any other element type is an error that names it.
pub fn f32_values(t: &TensorView<'_>) -> anyhow::Result<Vec<f32>> {
    anyhow::ensure!(t.dtype() == Dtype::F32, "the tensor is {:?}, need F32", t.dtype());
    Ok(t.data()
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes(c.try_into().expect("chunks of 4 bytes")))
        .collect())
}

/// Every tensor of the safetensors file at `path`, read through the bounded reader (a FIFO or
/// `/dev/zero` named as weights is refused, not read forever) and capped at the firmware's limit
/// for weights.
pub fn read_safetensors(path: &std::path::Path, dev: &candle_core::Device) -> anyhow::Result<HashMap<String, Tensor>> {
    use anyhow::Context;
    let bytes = input_file::read_capped(path, control::nn::MAX_WEIGHTS_BYTES)
        .with_context(|| format!("reading {}", path.display()))?;
    candle_core::safetensors::load_buffer(&bytes, dev)
        .with_context(|| format!("{} is not a safetensors file", path.display()))
}

/// Sets every variable of `vars` from the safetensors file at `path` (read as
/// [`read_safetensors`]); each must be there, in its shape.
pub fn load_vars(vars: &candle_nn::VarMap, path: &std::path::Path) -> anyhow::Result<()> {
    let tensors = read_safetensors(path, &candle_core::Device::Cpu)?;
    let data = vars.data().lock().expect("var map lock");
    for (name, var) in data.iter() {
        let t = tensors
            .get(name)
            .ok_or_else(|| anyhow::anyhow!("{} has no tensor {name}", path.display()))?;
        var.set(t)
            .map_err(|e| anyhow::anyhow!("{name} of {}: {e}", path.display()))?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tensors_round_trip_in_any_order_and_a_wrong_size_is_refused() {
        let a = NamedTensor::f32("b.weight", vec![2, 2], &[1.0, -2.0, 3.5, f32::MIN_POSITIVE]);
        let b = NamedTensor::f64("a.count", vec![1], &[12345.678]);
        let meta = HashMap::from([("k".to_string(), "v".to_string())]);
        let bytes = serialize(&[a.clone(), b.clone()], Some(meta.clone())).unwrap();
        assert_eq!(
            bytes,
            serialize(&[b.clone(), a.clone()], Some(meta)).unwrap(),
            "order-free"
        );
        let st = safetensors::SafeTensors::deserialize(&bytes).unwrap();
        for t in [&a, &b] {
            let v = st.tensor(&t.name).unwrap();
            assert_eq!((v.dtype(), v.shape(), v.data()), (t.dtype, &t.shape[..], &t.bytes[..]));
        }
        let (_, header) = safetensors::SafeTensors::read_metadata(&bytes).unwrap();
        assert_eq!(header.metadata().as_ref().unwrap()["k"], "v");
        assert_eq!(
            f32_values(&st.tensor("b.weight").unwrap()).unwrap(),
            [1.0, -2.0, 3.5, f32::MIN_POSITIVE]
        );
        let e = f32_values(&st.tensor("a.count").unwrap()).unwrap_err().to_string();
        assert!(e.contains("F64, need F32"), "{e}");
        let wrong = NamedTensor::f32("w", vec![3], &[1.0]);
        let e = serialize(&[wrong], None).unwrap_err().to_string();
        assert!(e.contains("do not match its shape"), "{e}");
    }

    #[test]
    fn a_candle_tensor_keeps_its_shape_and_values() {
        let t = Tensor::new(&[[1.0f32, 2.0, 3.0], [4.0, 5.0, 6.0]], &candle_core::Device::Cpu).unwrap();
        let n = NamedTensor::from_candle("x", &t).unwrap();
        assert_eq!(n, NamedTensor::f32("x", vec![2, 3], &[1.0, 2.0, 3.0, 4.0, 5.0, 6.0]));
    }
}
