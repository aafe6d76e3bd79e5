//! Where the networks run. A closed set chosen on the command line (`--device`); a GPU
//! backend is one more variant behind a cargo feature, and the model code, which takes
//! the device as a parameter, does not change.

use burn::prelude::*;

#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ComputeDevice {
    /// burn's flex backend on the CPU (all cores, through rayon).
    #[default]
    Cpu,
    /// burn's wgpu backend on the default adapter (cargo feature `wgpu`: Vulkan, Metal or
    /// DirectX; `CUBECL_WGPU_DEFAULT_DEVICE` picks another adapter).
    #[cfg(feature = "wgpu")]
    Wgpu,
}

impl ComputeDevice {
    #[cfg(not(feature = "wgpu"))]
    pub const NAMES: &[&str] = &["cpu"];
    #[cfg(feature = "wgpu")]
    pub const NAMES: &[&str] = &["cpu", "wgpu"];

    /// The inference device (wrap it with `.autodiff()` to train).
    pub fn device(self) -> Device {
        match self {
            ComputeDevice::Cpu => Device::flex(),
            #[cfg(feature = "wgpu")]
            ComputeDevice::Wgpu => Device::wgpu(burn::tensor::DeviceKind::DefaultDevice),
        }
    }
}

impl std::str::FromStr for ComputeDevice {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "cpu" => Ok(ComputeDevice::Cpu),
            #[cfg(feature = "wgpu")]
            "wgpu" => Ok(ComputeDevice::Wgpu),
            other => Err(format!(
                "unknown device `{other}`: this build has {} (GPU backends are cargo features)",
                Self::NAMES.join(", ")
            )),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cpu_is_the_default_and_unknown_names_are_refused() {
        assert_eq!("cpu".parse::<ComputeDevice>(), Ok(ComputeDevice::default()));
        let err = "cuda".parse::<ComputeDevice>().unwrap_err();
        assert!(err.contains("cuda") && err.contains("cpu"), "{err}");
    }
}
