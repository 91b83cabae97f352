//! Run-time backend choice: the CPU backends (flex; ndarray with the cargo feature `ndarray`), wgpu (cargo feature `wgpu`) and
//! CUDA (cargo feature `cuda`: burn's CUDA runtime, which loads the driver at run time, so it
//! builds without a CUDA toolkit).
//!
//! Owns: the mapping from a backend name to a burn `Device`. Must not touch: model code.

use burn::tensor::Device;
use std::str::FromStr;

#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum BackendKind {
    /// burn's pure-Rust CPU backend (gemm matmuls on rayon).
    Flex,
    /// burn-ndarray (deprecated upstream); only with the `ndarray` cargo feature.
    Ndarray,
    /// wgpu (Vulkan/Metal/DX12); only with the `wgpu` cargo feature.
    Wgpu,
    /// CUDA on the first NVIDIA GPU; only with the `cuda` cargo feature.
    Cuda,
}

impl BackendKind {
    /// The CPU default, chosen by `fipt-train bench step` measurements.
    pub const DEFAULT: BackendKind = BackendKind::Flex;

    /// The plain (inference) device of this backend.
    pub fn device(self) -> Result<Device, String> {
        match self {
            BackendKind::Flex => Ok(Device::flex()),
            BackendKind::Ndarray => ndarray_device(),
            BackendKind::Wgpu => wgpu_device(),
            BackendKind::Cuda => cuda_device(),
        }
    }

    /// Whether this is a GPU backend (where the hash grid goes on the device by default).
    pub fn is_gpu(self) -> bool {
        matches!(self, BackendKind::Wgpu | BackendKind::Cuda)
    }

    pub fn name(self) -> &'static str {
        match self {
            BackendKind::Flex => "flex",
            BackendKind::Ndarray => "ndarray",
            BackendKind::Wgpu => "wgpu",
            BackendKind::Cuda => "cuda",
        }
    }
}

#[cfg(feature = "wgpu")]
fn wgpu_device() -> Result<Device, String> {
    Ok(Device::wgpu(burn::tensor::DeviceKind::DefaultDevice))
}

#[cfg(not(feature = "wgpu"))]
fn wgpu_device() -> Result<Device, String> {
    Err("this build has no wgpu backend: rebuild with `--features wgpu`".into())
}

#[cfg(feature = "ndarray")]
fn ndarray_device() -> Result<Device, String> {
    #[allow(deprecated)]
    Ok(Device::ndarray())
}

#[cfg(not(feature = "ndarray"))]
fn ndarray_device() -> Result<Device, String> {
    Err("this build has no ndarray backend (deprecated upstream; flex is the CPU default): rebuild with `--features ndarray`".into())
}

#[cfg(feature = "cuda")]
fn cuda_device() -> Result<Device, String> {
    Ok(Device::cuda(0))
}

#[cfg(not(feature = "cuda"))]
fn cuda_device() -> Result<Device, String> {
    Err("this build has no CUDA backend: rebuild with `--features cuda`".into())
}

impl FromStr for BackendKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "flex" => Ok(BackendKind::Flex),
            "ndarray" => Ok(BackendKind::Ndarray),
            "wgpu" => Ok(BackendKind::Wgpu),
            "cuda" => Ok(BackendKind::Cuda),
            _ => Err(format!(
                "unknown backend '{s}' (expected flex, ndarray, wgpu or cuda)"
            )),
        }
    }
}
