//! What every CubeCL kernel of the project shares (cargo features `wgpu` and `cuda`): which
//! runtime a device is, and the launch shape of one thread per unit of work.

use burn::backend::ops::{FloatTensorOps, IntTensorOps};
use burn::prelude::*;
use burn::tensor::{DType, FloatDType, IntDType};
use burn_cubecl::CubeBackend;
use burn_cubecl::kernel::untile;
use burn_cubecl::ops::numeric::empty_device_dtype;
use burn_cubecl::tensor::CubeTensor;
use cubecl::prelude::{CubeCount, CubeDim};

/// The CubeCL runtime `device` runs on (wgpu, CUDA, …), or `None` for another backend (the
/// CPU's flex), where no CubeCL kernel applies.
pub fn cube_runtime(device: &Device) -> Option<cubecl::RuntimeId> {
    match device.clone().without_autodiff().as_dispatch() {
        burn::backend::DispatchDevice::Cube(cube) => Some(cube.runtime()),
        #[allow(unreachable_patterns)]
        _ => None,
    }
}

/// A float input as the kernels read it: f32, in rows (a matrix product's output may be
/// storage-tiled; its strides then order tiles, not rows).
pub fn float_rows(t: CubeTensor) -> CubeTensor {
    untile(CubeBackend::float_cast(t, FloatDType::F32))
}

/// An index input as the kernels read it: i32.
pub fn int_rows(t: CubeTensor) -> CubeTensor {
    CubeBackend::int_cast(t, IntDType::I32)
}

/// A one-dimensional f32 buffer of `len` values on `like`'s device, for a kernel's output:
/// no runtime pads a one-dimensional buffer (CUDA pads the rows of 2-D ones), so a kernel
/// can write it by index and relabel it with a reshape.
pub fn f32_buffer(like: &CubeTensor, len: usize) -> CubeTensor {
    buffer(like, len, DType::F32)
}

/// [`f32_buffer`] of i32 values: a kernel's index output.
pub fn i32_buffer(like: &CubeTensor, len: usize) -> CubeTensor {
    buffer(like, len, DType::I32)
}

fn buffer(like: &CubeTensor, len: usize, dtype: DType) -> CubeTensor {
    empty_device_dtype(
        like.client.clone(),
        like.device.clone(),
        [len].into(),
        dtype,
    )
}

pub use kernel_helpers::block_range;

/// What kernels of several modules call (CubeCL's prelude names `Tensor` apart from burn's).
mod kernel_helpers {
    use cubecl::prelude::*;

    /// In a kernel: block `block`'s range [first, end) of `len` values cut `block_len` at a
    /// time (the last block shorter), the blocked reductions' and scans' unit of serial work.
    #[cube]
    pub fn block_range(block: usize, block_len: u32, len: usize) -> (usize, usize) {
        let first = block * block_len as usize;
        let mut end = first + block_len as usize;
        if end > len {
            end = len;
        }
        (first, end)
    }
}

/// How `len` values (at least one) split into blocks of about √len for a two-pass reduction
/// or scan: (blocks, values a block), so that neither a block's thread nor the pass over the
/// blocks walks more than about √len values.
pub fn root_blocks(len: usize) -> (usize, usize) {
    let block_len = ((len as f64).sqrt().ceil() as usize).max(1);
    (len.div_ceil(block_len), block_len)
}

/// A one-dimensional launch over `units` threads.
pub fn launch_shape(client: &cubecl::client::Client, units: usize) -> (CubeCount, CubeDim) {
    let dim = CubeDim::new(client, units);
    (
        cubecl::calculate_cube_count_elemwise(client, units, dim),
        dim,
    )
}

/// The most bytes `device` binds to one buffer, so the largest tensor a kernel reads or
/// writes whole there (CubeCL's `max_page_size`; on wgpu the adapter's storage binding
/// limit), or `None` off CubeCL. On wgpu a larger tensor comes out wrong with no error
/// (burn 0.22 and CubeCL 0.11 do not check): Mesa's lavapipe binds 128 MiB.
pub fn binding_limit(device: &Device) -> Option<u64> {
    match device.clone().without_autodiff().as_dispatch() {
        burn::backend::DispatchDevice::Cube(cube) => {
            Some(cube.client().properties().memory.max_page_size)
        }
        #[allow(unreachable_patterns)]
        _ => None,
    }
}

/// burn's wgpu device, or `None` (with a line saying what was not checked) where no adapter
/// runs a kernel: for tests of GPU code on the CPU, where Mesa's lavapipe (Debian's
/// `mesa-vulkan-drivers`) is enough.
#[cfg(feature = "wgpu")]
pub fn working_wgpu_device(unchecked: &str) -> Option<Device> {
    let device = Device::wgpu(burn::tensor::DeviceKind::DefaultDevice);
    let probe = device.clone();
    let sum = std::panic::catch_unwind(move || {
        Tensor::<1>::from_floats([1.0, 2.0], &probe)
            .sum()
            .into_scalar::<f32>()
    });
    match sum {
        Ok(3.0) => Some(device),
        _ => {
            eprintln!("skipped: no wgpu adapter ran a kernel; {unchecked} was not checked");
            None
        }
    }
}

/// Asserts every value of `got` within `tolerance` times the largest |value| of `want` (at
/// least 1) of `want`'s: a GPU's results against the CPU's, in the tests of GPU code.
#[cfg(feature = "wgpu")]
pub fn assert_close(got: &[f32], want: &[f32], tolerance: f32, what: &str) {
    assert_eq!(got.len(), want.len(), "{what}");
    let scale = want.iter().fold(1f32, |m, v| m.max(v.abs()));
    for (i, (x, y)) in got.iter().zip(want).enumerate() {
        assert!(
            (x - y).abs() <= tolerance * scale,
            "{what}[{i}]: {x} vs {y}"
        );
    }
}

/// A fixed, varied upstream gradient for an output of `dims` on `device`: the loss
/// `(output · upstream).sum()` sends it back (the GPU tests' gradients).
#[cfg(feature = "wgpu")]
pub fn upstream(dims: [usize; 2], device: &Device) -> Tensor<2> {
    let values: Vec<f32> = (0..dims[0] * dims[1])
        .map(|v| ((v * 53) % 97) as f32 / 48.0 - 1.0)
        .collect();
    Tensor::from_data(TensorData::new(values, dims), device)
}

#[cfg(all(test, feature = "wgpu"))]
mod tests {
    use super::*;

    /// A CubeCL device states how much one buffer binds (lavapipe: 128 MiB), the CPU nothing.
    #[test]
    fn cubecl_devices_state_their_binding_limit() {
        let Some(gpu) = working_wgpu_device("the binding limit") else {
            return;
        };
        let limit = binding_limit(&gpu).expect("a CubeCL device");
        assert!(limit >= 1 << 20, "{limit} bytes");
        assert_eq!(binding_limit(&gpu.autodiff()), Some(limit));
        assert_eq!(binding_limit(&Device::flex()), None);
    }
}
