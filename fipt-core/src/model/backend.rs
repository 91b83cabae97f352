//! Run-time backend choice: the CPU backends (flex; ndarray with the cargo feature `ndarray`)
//! and wgpu (cargo feature `wgpu`). burn's CUDA runtime is not offered: cubecl-cuda 0.11 builds
//! cubecl-llvm, whose build script downloads an LLVM bundle from outside any package registry,
//! so it does not build on a machine that reaches only the registries.
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
        }
    }

    /// Whether this is a GPU backend (where the hash grid goes on the device by default).
    pub fn is_gpu(self) -> bool {
        matches!(self, BackendKind::Wgpu)
    }

    pub fn name(self) -> &'static str {
        match self {
            BackendKind::Flex => "flex",
            BackendKind::Ndarray => "ndarray",
            BackendKind::Wgpu => "wgpu",
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

impl FromStr for BackendKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "flex" => Ok(BackendKind::Flex),
            "ndarray" => Ok(BackendKind::Ndarray),
            "wgpu" => Ok(BackendKind::Wgpu),
            _ => Err(format!(
                "unknown backend '{s}' (expected flex, wgpu or ndarray)"
            )),
        }
    }
}
