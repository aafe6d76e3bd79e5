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
    /// burn's CUDA backend on the NVIDIA device with this index, as the driver numbers them
    /// (cargo feature `cuda`; `CUDA_VISIBLE_DEVICES` applies). Kernels are compiled by NVRTC
    /// at run time; the driver and NVRTC are loaded when the device is first used.
    #[cfg(feature = "cuda")]
    Cuda(usize),
}

impl ComputeDevice {
    /// The names `--device` accepts in this build (`cuda` also as `cuda:N`).
    pub const NAMES: &[&str] = &[
        "cpu",
        #[cfg(feature = "wgpu")]
        "wgpu",
        #[cfg(feature = "cuda")]
        "cuda",
    ];

    /// The inference device (wrap it with `.autodiff()` to train).
    pub fn device(self) -> Device {
        match self {
            ComputeDevice::Cpu => Device::flex(),
            #[cfg(feature = "wgpu")]
            ComputeDevice::Wgpu => {
                crate::kernel_cache::configure();
                let device = Device::wgpu(burn::tensor::DeviceKind::DefaultDevice);
                note_small_binding_limit(&device);
                device
            }
            #[cfg(feature = "cuda")]
            ComputeDevice::Cuda(index) => {
                crate::kernel_cache::configure();
                Device::cuda(index)
            }
        }
    }

    /// Whether the device can run a kernel here. The CPU always can; a GPU is asked to sum a
    /// small tensor, and a backend that panics for want of a driver or adapter gives an
    /// error carrying the panic's message instead. For CUDA, the driver's device list is
    /// read first, which needs no kernel and does not panic without a driver.
    ///
    /// While a probe runs the panic hook is silenced (it is process-wide: a panic on
    /// another thread in that moment is not printed, though it still unwinds).
    pub fn check(self) -> Result<(), String> {
        match self {
            ComputeDevice::Cpu => Ok(()),
            #[cfg(feature = "wgpu")]
            ComputeDevice::Wgpu => {
                probe(self.device()).map_err(|e| format!("no wgpu adapter could run a kernel: {e}"))
            }
            #[cfg(feature = "cuda")]
            ComputeDevice::Cuda(index) => {
                crate::kernel_cache::configure();
                let found = silenced(|| Device::enumerate(burn::tensor::DeviceType::Cuda).len())
                    .map_err(|e| format!("no CUDA device/driver found: {e}"))?;
                if found == 0 {
                    return Err(
                        "no CUDA device/driver found: the NVIDIA driver (libcuda.so) \
                                could not be loaded or lists no devices"
                            .into(),
                    );
                }
                if index >= found {
                    return Err(format!(
                        "no CUDA device/driver found: cuda:{index} asked for, the driver lists \
                         {found} device(s), cuda:0 to cuda:{}",
                        found - 1
                    ));
                }
                probe(self.device()).map_err(|e| format!("CUDA device {index} failed: {e}"))
            }
        }
    }

    /// The name alone, without looking for the device ([`FromStr`](std::str::FromStr) also
    /// checks a CUDA device).
    fn parse_name(s: &str) -> Result<Self, String> {
        match s {
            "cpu" => return Ok(ComputeDevice::Cpu),
            #[cfg(feature = "wgpu")]
            "wgpu" => return Ok(ComputeDevice::Wgpu),
            #[cfg(not(feature = "wgpu"))]
            "wgpu" => return Err(Self::needs_feature(s, "wgpu")),
            _ => {}
        }
        if let Some(index) = cuda_index(s) {
            #[cfg(feature = "cuda")]
            return index.map(ComputeDevice::Cuda);
            #[cfg(not(feature = "cuda"))]
            return index.and(Err(Self::needs_feature(s, "cuda")));
        }
        Err(format!(
            "unknown device `{s}`: this build has {} (GPU backends are cargo features)",
            Self::NAMES.join(", ")
        ))
    }

    #[cfg(any(not(feature = "wgpu"), not(feature = "cuda")))]
    fn needs_feature(name: &str, feature: &str) -> String {
        format!(
            "device `{name}` needs a build with the cargo feature `{feature}`; this build has {}",
            Self::NAMES.join(", ")
        )
    }
}

/// The binding limit under which a wgpu adapter's results are not to be trusted for every
/// configuration: 1 GiB (real GPUs bind 2–4 GiB or more; Mesa's lavapipe 128 MiB).
#[cfg(feature = "wgpu")]
const SMALL_BINDING_LIMIT: u64 = 1 << 30;

/// Says once a process, where the wgpu adapter binds less than [`SMALL_BINDING_LIMIT`] to
/// one buffer, that a larger tensor comes out wrong there without an error: burn and CubeCL
/// do not check. LFA's inference splits its largest sums to stay under the limit (the
/// shipped SAF model's passed lavapipe's 128 MiB from 9 frustums a batch); nothing else
/// does.
#[cfg(feature = "wgpu")]
fn note_small_binding_limit(device: &Device) {
    static NOTED: std::sync::Once = std::sync::Once::new();
    NOTED.call_once(|| {
        let limit = fusiondet_nn::cube::binding_limit(device);
        if let Some(limit) = limit.filter(|&l| l < SMALL_BINDING_LIMIT) {
            eprintln!(
                "note: this wgpu adapter binds at most {} MiB to one tensor; a larger tensor \
                 comes out wrong without an error (burn and CubeCL do not check), so results \
                 that need one are not the CPU's: the shipped models' detection stays under \
                 it, training large configurations may not (docs/gpus-and-clusters.md)",
                limit >> 20
            );
        }
    });
}

/// `cuda` is device 0, `cuda:N` device N; `None` for a name that is not CUDA's.
fn cuda_index(s: &str) -> Option<Result<usize, String>> {
    let rest = s.strip_prefix("cuda")?;
    if rest.is_empty() {
        return Some(Ok(0));
    }
    let number = rest.strip_prefix(':')?;
    Some(
        number
            .parse()
            .map_err(|_| format!("`{s}`: a CUDA device index is a number, as in cuda:1")),
    )
}

/// Runs `f`, turning a panic into its message, without the panic hook printing it.
#[cfg(any(feature = "wgpu", feature = "cuda"))]
fn silenced<T>(f: impl FnOnce() -> T) -> Result<T, String> {
    let hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(|_| {}));
    let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(f));
    std::panic::set_hook(hook);
    result.map_err(|payload| {
        payload
            .downcast_ref::<String>()
            .cloned()
            .or_else(|| payload.downcast_ref::<&str>().map(|s| s.to_string()))
            .unwrap_or_else(|| "the backend panicked".into())
    })
}

/// Sums [1, 2, 3] on the device.
#[cfg(any(feature = "wgpu", feature = "cuda"))]
fn probe(device: Device) -> Result<(), String> {
    let sum = silenced(move || {
        Tensor::<1>::from_floats([1.0, 2.0, 3.0], &device)
            .sum()
            .into_scalar::<f32>()
    })?;
    if (sum - 6.0).abs() < 1e-6 {
        Ok(())
    } else {
        Err(format!("a test sum gave {sum} instead of 6"))
    }
}

impl std::str::FromStr for ComputeDevice {
    type Err = String;
    /// Parses `--device`. A CUDA device is also checked ([`ComputeDevice::check`]), so that a
    /// machine without the driver or the device is told so here rather than by a panic in
    /// the backend later; wgpu is not (it has no cheap device list to read).
    fn from_str(s: &str) -> Result<Self, String> {
        let device = Self::parse_name(s)?;
        #[cfg(feature = "cuda")]
        if let ComputeDevice::Cuda(_) = device {
            device.check()?;
        }
        Ok(device)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cpu_is_the_default_and_unknown_names_are_refused() {
        assert_eq!("cpu".parse::<ComputeDevice>(), Ok(ComputeDevice::default()));
        assert_eq!(ComputeDevice::Cpu.check(), Ok(()));
        for name in ["tpu", "cudax", "CPU", ""] {
            let err = name.parse::<ComputeDevice>().unwrap_err();
            assert!(
                err.contains("unknown device") && err.contains("cpu"),
                "{err}"
            );
        }
    }

    #[cfg(not(feature = "cuda"))]
    #[test]
    fn cuda_is_refused_naming_the_feature_without_it() {
        for name in ["cuda", "cuda:1"] {
            let err = name.parse::<ComputeDevice>().unwrap_err();
            assert!(err.contains("cargo feature `cuda`"), "{err}");
        }
        // A malformed index is reported as such either way.
        let err = "cuda:one".parse::<ComputeDevice>().unwrap_err();
        assert!(err.contains("index"), "{err}");
    }

    #[cfg(not(feature = "wgpu"))]
    #[test]
    fn wgpu_is_refused_naming_the_feature_without_it() {
        let err = "wgpu".parse::<ComputeDevice>().unwrap_err();
        assert!(err.contains("cargo feature `wgpu`"), "{err}");
    }

    #[cfg(feature = "cuda")]
    #[test]
    fn cuda_names_give_device_indices_and_a_missing_device_is_an_error() {
        let parse = ComputeDevice::parse_name;
        assert_eq!(parse("cuda"), Ok(ComputeDevice::Cuda(0)));
        assert_eq!(parse("cuda:3"), Ok(ComputeDevice::Cuda(3)));
        assert!(parse("cuda:one").unwrap_err().contains("index"));
        assert!(parse("cuda:-1").is_err());
        // Device 4096 exists nowhere; device 0 only where a driver and a GPU are.
        let err = "cuda:4096".parse::<ComputeDevice>().unwrap_err();
        assert!(err.starts_with("no CUDA device/driver found"), "{err}");
        match "cuda".parse::<ComputeDevice>() {
            Ok(device) => assert_eq!(device, ComputeDevice::Cuda(0)),
            Err(err) => assert!(err.contains("CUDA device"), "{err}"),
        }
    }
}
