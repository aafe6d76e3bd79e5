//! Where the networks run. A closed set chosen on the command line (`--device`); a GPU
//! backend is one more variant behind a cargo feature, and the model code, which takes
//! the device as a parameter, does not change.

use burn::prelude::*;

#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ComputeDevice {
    /// burn's flex backend on the CPU (all cores, through rayon).
    #[default]
    Cpu,
}

impl ComputeDevice {
    pub const NAMES: [&str; 1] = ["cpu"];

    /// The inference device (wrap it with `.autodiff()` to train).
    pub fn device(self) -> Device {
        match self {
            ComputeDevice::Cpu => Device::flex(),
        }
    }
}

impl std::str::FromStr for ComputeDevice {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "cpu" => Ok(ComputeDevice::Cpu),
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
