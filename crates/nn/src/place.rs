//! Where a step that has both a host and a device implementation runs (the RoI grid query,
//! stage one's proposals): the host on the CPU; on a GPU backend's device the device, unless
//! an environment variable of the step's own says `host`, `device` or `check`. And the
//! on/off switches the environment sets the same way (the custom operations, the inner
//! split).

use burn::prelude::*;
use std::sync::OnceLock;

/// Where a step runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Place {
    /// On the host, its result uploaded where the network needs it there.
    Host,
    /// In the device's kernels.
    Device,
    /// Both: the host's result used, the device's compared with it and each difference
    /// reported.
    Check,
}

impl Place {
    /// The host off CubeCL (the CPU); on a CubeCL device `variable` (`host`, `device` or
    /// `check`) where set, else the device. The variable is read once a process, into
    /// `read` (a static of the step's own); a value not understood is warned of once and
    /// leaves the default.
    pub fn for_device(
        device: &Device,
        variable: &'static str,
        read: &'static OnceLock<Option<Place>>,
    ) -> Place {
        #[cfg(any(feature = "wgpu", feature = "cuda"))]
        if crate::cube::cube_runtime(device).is_some() {
            return Self::from_env(variable, read).unwrap_or(Place::Device);
        }
        let _ = (device, variable, read);
        Place::Host
    }

    #[cfg(any(feature = "wgpu", feature = "cuda"))]
    fn from_env(variable: &'static str, read: &'static OnceLock<Option<Place>>) -> Option<Place> {
        *read.get_or_init(|| match std::env::var(variable).as_deref() {
            Err(_) => None,
            Ok("host") => Some(Place::Host),
            Ok("device") => Some(Place::Device),
            Ok("check") => Some(Place::Check),
            Ok(value) => {
                eprintln!(
                    "warning: {variable}={value:?} is not \"host\", \"device\" or \"check\"; \
                     the step runs where this device's default puts it"
                );
                None
            }
        })
    }
}

/// A switch a process reads once from `variable` into `read` (a static of the switch's own):
/// on when unset or `on`, off when `off`; any other value is warned of once, saying
/// `stays` (what the default keeps), and leaves the switch on.
pub fn switch_on_unless_off(variable: &str, read: &OnceLock<bool>, stays: &str) -> bool {
    *read.get_or_init(|| match std::env::var(variable).as_deref() {
        Err(_) | Ok("on") => true,
        Ok("off") => false,
        Ok(value) => {
            eprintln!("warning: {variable}={value:?} is neither \"on\" nor \"off\"; {stays}");
            true
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_cpu_runs_every_step_on_the_host() {
        static READ: OnceLock<Option<Place>> = OnceLock::new();
        assert_eq!(
            Place::for_device(&Device::flex(), "FUSIONDET_PLACE_TEST", &READ),
            Place::Host
        );
    }
}
