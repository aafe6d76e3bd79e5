//! Experiment configurations: any TOML is accepted (and then validated) or refused with an
//! error, never a panic, and an accepted one round-trips through its own TOML.
#![no_main]

use fusiondet_pipeline::ExperimentConfig;
use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let path = Path::new("fuzz.toml");
    if let Ok(config) = ExperimentConfig::from_toml_str(text, path) {
        let back = ExperimentConfig::from_toml_str(&config.to_toml_string(), path)
            .expect("a configuration we accept writes a file we accept");
        assert_eq!(back, config);
    }
});
