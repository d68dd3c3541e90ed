//! Edits of an optimizer's per-parameter state tensors (Adam's moments) in place of burn's
//! private record fields: the state goes through its burnpack form, and each f32 tensor of a
//! parameter may be replaced (densification's row gathers, a table layout change on resume).

use burn::optim::ModuleOptimizer;
use burn::tensor::DType;

use crate::error::{OpsError, Result};

/// One state tensor as the editor sees it: its parameter's id, its shape and its values.
pub struct StateTensor<'a> {
    pub param_id: u64,
    pub shape: &'a [usize],
    pub values: Vec<f32>,
}

/// Passes every f32 state tensor that belongs to a parameter to `edit`, which returns the
/// replacement `(values, shape)` or `None` to keep it; other entries are kept as they are.
pub fn edit_state(
    optim: ModuleOptimizer,
    mut edit: impl FnMut(StateTensor<'_>) -> Option<(Vec<f32>, Vec<usize>)>,
) -> Result<ModuleOptimizer> {
    let err = |e: &dyn std::fmt::Debug| OpsError::invalid(format!("optimizer state: {e:?}"));
    let bytes = optim.into_bytes().map_err(|e| err(&e))?;
    let reader = burn_pack::Reader::from_bytes(bytes).map_err(|e| err(&e))?;
    let scalars = reader.scalars().clone();
    let metadata = reader.metadata().clone();
    let tensors = reader.into_tensors().map_err(|e| err(&e))?;
    let mut edited = Vec::with_capacity(tensors.len());
    for t in tensors {
        let (name, dtype, shape, param_id, bytes) = t.into_parts().map_err(|e| err(&e))?;
        let replaced = match param_id {
            Some(id) if dtype == DType::F32 => {
                let dims: Vec<usize> = shape.iter().copied().collect();
                let values = bytes.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect();
                edit(StateTensor { param_id: id, shape: &dims, values })
            }
            _ => None,
        };
        edited.push(match replaced {
            Some((values, dims)) => {
                let raw: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
                burn_pack::Tensor::new(name, dtype, dims, param_id, burn::tensor::Bytes::from_bytes_vec(raw))
            }
            None => burn_pack::Tensor::new(name, dtype, shape, param_id, bytes),
        });
    }
    let mut writer = burn_pack::Writer::new(edited);
    for (k, v) in &scalars {
        writer = writer.with_scalar(k, *v);
    }
    for (k, v) in &metadata {
        writer = writer.with_metadata(k, v);
    }
    let bytes = writer.into_bytes().map_err(|e| err(&e))?;
    optim.from_bytes(bytes).map_err(|e| err(&e))
}
