//! Training with the custom flex operations (`fusiondet_nn::ragged`: the ragged max-pool,
//! LFA's neighbour sum and max, batch norm over rows) against training with burn's generic
//! operations, for the network of every shipped tiny frustum configuration
//! (`configs/tiny*.toml` of kind `frustum`): the same loss curve within float tolerance,
//! and the custom path bit-reproducible run to run.
//!
//! One test in this file: the switch between the paths is process-wide.

use burn::optim::{AdamConfig, GradientsParams};
use burn::prelude::*;
use fusiondet_models::synthetic::{SyntheticSpec, lfa_batch, synthetic_batch};
use fusiondet_models::*;
use fusiondet_nn::ragged::set_custom_ops;
use std::path::{Path, PathBuf};

/// The frustum family's tiny configurations, with the network and loss sections of each.
fn tiny_frustum_configs() -> Vec<(PathBuf, FConvNetConfig)> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs");
    let mut paths: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| {
            let name = p.file_name().unwrap().to_string_lossy();
            name.starts_with("tiny") && name.ends_with(".toml")
        })
        .collect();
    paths.sort();
    paths
        .into_iter()
        .filter_map(|path| {
            let text = std::fs::read_to_string(&path).unwrap();
            let table: toml::Table = text.parse().unwrap();
            let kind = table["detector"]["kind"].as_str().unwrap().to_string();
            if kind != "frustum" {
                return None;
            }
            let mut sections = toml::Table::new();
            for key in ["model", "loss"] {
                if let Some(v) = table.get(key) {
                    sections.insert(key.into(), v.clone());
                }
            }
            let mut config: FConvNetConfig = toml::Value::Table(sections).try_into().unwrap();
            // The synthetic batch holds KITTI's classes and size clusters (the SUN RGB-D
            // configuration's ten classes change only the heads' widths).
            let car = ModelConfig::car();
            config.model.num_classes = car.num_classes;
            config.model.size_clusters = car.size_clusters;
            Some((path, config))
        })
        .collect()
}

/// Losses of `steps` Adam steps from seed 5, and the final weights.
fn train(config: &FConvNetConfig, custom: bool, steps: usize) -> (Vec<f32>, Vec<f64>) {
    set_custom_ops(custom);
    let device = Device::flex().autodiff();
    device.seed(5);
    let mut model = FConvNet::new(&config.model, &device).unwrap();
    let spec = SyntheticSpec::tiny(6);
    let batch = match &config.model.lfa {
        Some(lfa) => lfa_batch(&spec, 3, 1 << lfa.stages.len()),
        None => synthetic_batch(&spec, 3),
    };
    let inputs = model.inputs(&batch, &device).unwrap();
    let targets = LossTargets::new(&batch, &config.model, &config.loss, &device).unwrap();
    let mut optim = AdamConfig::new().init();
    let mut losses = vec![];
    for _ in 0..steps {
        let loss = fconvnet_loss(&model.forward_inputs(&inputs), &targets, &config.loss).unwrap();
        losses.push(loss.components.total);
        let grads = GradientsParams::from_grads(loss.total.backward(), &model);
        model = optim.step(2e-3, model, grads);
    }
    let mut weights = Weights(Vec::new());
    model.visit(&mut weights);
    set_custom_ops(true);
    (losses, weights.0)
}

/// Every float parameter's values, in visiting order.
struct Weights(Vec<f64>);

impl burn::module::ModuleVisitor for Weights {
    fn visit_float<const D: usize>(&mut self, param: &burn::module::Param<Tensor<D>>) {
        let values = param.val().try_into_vec_as::<f32>().unwrap();
        self.0.extend(values.into_iter().map(f64::from));
    }
}

#[test]
fn custom_operations_keep_each_tiny_configs_loss_curve_and_reproduce_bit_for_bit() {
    let configs = tiny_frustum_configs();
    assert!(
        configs.len() >= 10,
        "the tiny frustum configurations: {configs:?}"
    );
    let steps = 12;
    for (path, config) in &configs {
        let name = path.file_name().unwrap().to_string_lossy();
        let (generic, _) = train(config, false, steps);
        let (custom, custom_w) = train(config, true, steps);
        println!("{name}: generic {generic:?}\n{name}: custom  {custom:?}");
        assert!(
            custom.last().unwrap() < custom.first().unwrap(),
            "{name}: the loss falls"
        );
        // Step 0 is one forward from the same weights: rounding alone. After it, Adam
        // carries the rounding differences forward and they grow slowly; the curves
        // (falling ten-fold over these steps) stay within 2% of each other. (Most within
        // 0.3%; the projection loss amplifies them most: tiny-saf and tiny-saf-lfa-pl part
        // by 1.0e-2 since the matrix products take AVX-512 kernels, which round otherwise.)
        let relative = |a: f32, b: f32| (a - b).abs() / a.abs().max(1.0);
        assert!(
            relative(generic[0], custom[0]) <= 1e-5,
            "{name}: step 0: generic {} vs custom {}",
            generic[0],
            custom[0]
        );
        let mut worst = 0f32;
        for (step, (&a, &b)) in generic.iter().zip(&custom).enumerate() {
            assert!(
                relative(a, b) <= 2e-2,
                "{name}: step {step}: generic {a} vs custom {b}"
            );
            worst = worst.max(relative(a, b));
        }
        println!("{name}: largest relative difference {worst:.1e}");
        // Run to run, the custom path gives the same bits.
        let (again, again_w) = train(config, true, steps);
        assert_eq!(
            custom.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
            again.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
            "{name}: losses run to run"
        );
        assert_eq!(custom_w, again_w, "{name}: weights run to run");
    }
}
