//! Where a GPU build keeps its compiled kernels and autotune results between runs.
//!
//! burn's GPU backends (CubeCL) compile every kernel at run time (NVRTC for CUDA) and tune
//! the ones with several variants by timing them: 10–16 s before the first frame of every
//! process on an H100. CubeCL can keep both on disk, but by default it keeps compiled
//! kernels nowhere and puts the tuning results under the `target/` of the Cargo workspace
//! around the current directory (a user's cache folder outside one), so an installed
//! `fusiondet` paid the compilation again in every process. Here both go to one folder the
//! user can name, and compiled kernels are kept.
//!
//! The folder: `FUSIONDET_KERNEL_CACHE` (a directory; `off` keeps nothing on disk), else
//! `$XDG_CACHE_HOME/fusiondet/kernels`, else `$HOME/.cache/fusiondet/kernels`. A CubeCL
//! configuration file the user wrote (`cubecl.toml`, or a `[cubecl]` section in `burn.toml`,
//! in the current directory or above) is left to CubeCL, unchanged.
//!
//! `FUSIONDET_AUTOTUNE_LOG` names a file autotune appends its choices to (the kernel it kept
//! for each tuned shape, with its timings): which convolution and product kernels a GPU
//! ended up running, without CubeCL's full debug log.
//!
//! `FUSIONDET_KERNEL_PROFILE` names a file CubeCL's profiler appends a record to for every
//! kernel launch, at its `full` level: the time the device spent in it, the kernel with its
//! compile-time arguments and the cube count it was launched with (`| 41.2µs | name…`,
//! `CubeCount (x, y, z)`): where a GPU's time goes, kernel by kernel, and which launches give
//! the GPU too few cubes to fill it (`scripts/gpu-check.sh` sums it per kernel). Each launch
//! is then timed on its own, so the process runs slower; time a run without it.

use std::path::{Path, PathBuf};

/// Where the caches go, from the three environment variables (read by the caller); `None`
/// when caching is turned off or no folder can be named.
pub fn cache_dir(
    fusiondet_kernel_cache: Option<&str>,
    xdg_cache_home: Option<&str>,
    home: Option<&str>,
) -> Option<PathBuf> {
    if let Some(dir) = nonempty(fusiondet_kernel_cache) {
        return (dir != "off").then(|| PathBuf::from(dir));
    }
    // XDG: a relative XDG_CACHE_HOME is invalid and ignored.
    if let Some(xdg) = nonempty(xdg_cache_home).filter(|d| Path::new(d).is_absolute()) {
        return Some(Path::new(xdg).join("fusiondet/kernels"));
    }
    nonempty(home).map(|h| Path::new(h).join(".cache/fusiondet/kernels"))
}

fn nonempty(v: Option<&str>) -> Option<&str> {
    v.filter(|s| !s.trim().is_empty())
}

/// Whether a CubeCL configuration file lies in `dir` or a folder above it.
pub fn user_config_above(dir: &Path) -> Option<PathBuf> {
    const NAMES: [&str; 4] = ["cubecl.toml", "CubeCL.toml", "burn.toml", "Burn.toml"];
    dir.ancestors()
        .flat_map(|d| NAMES.iter().map(move |n| d.join(n)))
        .find(|p| p.is_file())
}

/// Sets CubeCL's configuration before the first GPU device starts (later calls do nothing;
/// a configuration CubeCL already loaded is kept).
#[cfg(any(feature = "wgpu", feature = "cuda"))]
pub fn configure() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        use cubecl_runtime::config::{CubeClRuntimeConfig, RuntimeConfig};
        let here = std::env::current_dir().unwrap_or_default();
        if user_config_above(&here).is_some() {
            return;
        }
        // CUBECL_* variables still apply on top (autotune level, logging, ...).
        let config = runtime_config(CubeClRuntimeConfig::default().override_from_env(), |k| {
            std::env::var(k).ok()
        });
        // False when CubeCL already read its configuration: that one stays.
        CubeClRuntimeConfig::try_set(config);
    });
}

/// `config` with the cache folder, the autotune log and the kernel profile that the
/// environment (`env`, a variable's value by name) asks for.
#[cfg(any(feature = "wgpu", feature = "cuda"))]
fn runtime_config(
    mut config: cubecl_runtime::config::CubeClRuntimeConfig,
    env: impl Fn(&str) -> Option<String>,
) -> cubecl_runtime::config::CubeClRuntimeConfig {
    use cubecl_runtime::config::cache::CacheConfig;
    let dir = cache_dir(
        env("FUSIONDET_KERNEL_CACHE").as_deref(),
        env("XDG_CACHE_HOME").as_deref(),
        env("HOME").as_deref(),
    );
    match dir {
        Some(dir) => {
            config.compilation.cache = true;
            config.environment.path = CacheConfig::Directory(dir);
        }
        None => config.autotune.disable_cache = true,
    }
    if let Some(log) = nonempty(env("FUSIONDET_AUTOTUNE_LOG").as_deref()) {
        config.autotune.logger.file = Some(PathBuf::from(log));
        config.autotune.logger.append = true;
    }
    if let Some(log) = nonempty(env("FUSIONDET_KERNEL_PROFILE").as_deref()) {
        use cubecl_runtime::config::profiling::ProfilingLogLevel;
        config.profiling.logger.file = Some(PathBuf::from(log));
        config.profiling.logger.append = true;
        config.profiling.logger.level = ProfilingLogLevel::Full;
    }
    config
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_cache_folder_follows_the_variables_in_order() {
        let d = |a, b, c| cache_dir(a, b, c);
        assert_eq!(
            d(Some("/k"), Some("/x"), Some("/h")),
            Some(PathBuf::from("/k"))
        );
        assert_eq!(d(Some("off"), Some("/x"), Some("/h")), None);
        assert_eq!(
            d(None, Some("/x"), Some("/h")),
            Some(PathBuf::from("/x/fusiondet/kernels"))
        );
        // An empty or relative XDG_CACHE_HOME is ignored, as XDG says.
        assert_eq!(
            d(Some(""), Some("rel"), Some("/h")),
            Some(PathBuf::from("/h/.cache/fusiondet/kernels"))
        );
        assert_eq!(d(None, None, None), None);
    }

    #[test]
    fn a_user_cubecl_file_above_is_found() {
        let root = tempfile::tempdir().unwrap();
        let deep = root.path().join("a/b");
        std::fs::create_dir_all(&deep).unwrap();
        // Only a file above the temporary folder (none on a clean machine) is found.
        let outside = user_config_above(root.path().parent().unwrap());
        assert_eq!(user_config_above(&deep), outside);
        std::fs::write(root.path().join("burn.toml"), "[cubecl]\n").unwrap();
        assert_eq!(
            user_config_above(&deep),
            Some(root.path().join("burn.toml"))
        );
    }

    /// The folder, the autotune log and the kernel profile reach CubeCL's configuration;
    /// without them the tuning results stay in memory and nothing is logged to a file.
    #[cfg(any(feature = "wgpu", feature = "cuda"))]
    #[test]
    fn kernel_cache_config_takes_the_folder_the_autotune_log_and_the_profile() {
        use cubecl_runtime::config::{CubeClRuntimeConfig, cache::CacheConfig};
        let vars = |pairs: &'static [(&'static str, &'static str)]| {
            move |k: &str| {
                pairs
                    .iter()
                    .find(|(n, _)| *n == k)
                    .map(|(_, v)| v.to_string())
            }
        };
        let config = runtime_config(
            CubeClRuntimeConfig::default(),
            vars(&[
                ("FUSIONDET_KERNEL_CACHE", "/k"),
                ("FUSIONDET_AUTOTUNE_LOG", "/k/tune.log"),
                ("FUSIONDET_KERNEL_PROFILE", "/k/profile.log"),
            ]),
        );
        assert!(config.compilation.cache && !config.autotune.disable_cache);
        assert!(
            matches!(&config.environment.path, CacheConfig::Directory(d) if d == Path::new("/k"))
        );
        assert_eq!(
            config.autotune.logger.file,
            Some(PathBuf::from("/k/tune.log"))
        );
        assert_eq!(
            config.profiling.logger.file,
            Some(PathBuf::from("/k/profile.log"))
        );
        assert!(config.profiling.logger.append);
        assert!(matches!(
            config.profiling.logger.level,
            cubecl_runtime::config::profiling::ProfilingLogLevel::Full
        ));
        let config = runtime_config(
            CubeClRuntimeConfig::default(),
            vars(&[
                ("FUSIONDET_KERNEL_CACHE", "off"),
                ("FUSIONDET_AUTOTUNE_LOG", " "),
            ]),
        );
        assert!(config.autotune.disable_cache);
        assert_eq!(config.autotune.logger.file, None);
        assert_eq!(config.profiling.logger.file, None);
        assert!(matches!(
            config.profiling.logger.level,
            cubecl_runtime::config::profiling::ProfilingLogLevel::Disabled
        ));
    }
}
