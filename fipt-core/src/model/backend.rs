//! Run-time backend choice: the CPU backends (flex, ndarray) and wgpu (cargo feature `wgpu`).
//!
//! Owns: the mapping from a backend name to a burn `Device`. Must not touch: model code.

use burn::tensor::Device;
use std::str::FromStr;

#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum BackendKind {
    /// burn's pure-Rust CPU backend (gemm matmuls on rayon).
    Flex,
    /// burn-ndarray (deprecated upstream, kept selectable).
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
            #[allow(deprecated)]
            BackendKind::Ndarray => Ok(Device::ndarray()),
            BackendKind::Wgpu => wgpu_device(),
        }
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

impl FromStr for BackendKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "flex" => Ok(BackendKind::Flex),
            "ndarray" => Ok(BackendKind::Ndarray),
            "wgpu" => Ok(BackendKind::Wgpu),
            _ => Err(format!(
                "unknown backend '{s}' (expected flex, ndarray or wgpu)"
            )),
        }
    }
}
