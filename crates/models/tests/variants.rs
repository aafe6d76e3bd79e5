//! The seeds' variants of F-ConvNet: FCAM's attention, SAF's LFA and projection loss —
//! parameter counts, training behaviour and the projection term by hand.

use burn::module::Param;
use burn::optim::{AdamConfig, GradientsParams};
use burn::prelude::*;
use fusiondet_models::boxes::box_corners;
use fusiondet_models::loss::{box_corners_tensor, projected_box, projection_loss};
use fusiondet_models::synthetic::{SyntheticSpec, lfa_batch, synthetic_batch};
use fusiondet_models::*;

fn params(config: &ModelConfig) -> usize {
    info::trainable_params(&FConvNet::new(config, &Device::flex()).unwrap())
}

fn with_encoder(kind: SliceEncoderKind) -> ModelConfig {
    ModelConfig {
        slice_encoder: kind,
        ..ModelConfig::car()
    }
}

fn with_lfa() -> ModelConfig {
    ModelConfig {
        lfa: Some(LfaConfig::default()),
        ..ModelConfig::car()
    }
}

#[test]
fn parameter_counts_of_the_variants() {
    let base = 3_316_777;
    // CBAM after each PointNet's first layer (64/64/128/256 channels): bias-free channel
    // MLPs C → C/16 → C (C²/8 each: 512 + 512 + 2048 + 8192 = 11,264, FCAM's published
    // difference) plus a 2 → 1 7 × 7 spatial kernel (98) per block.
    assert_eq!(
        params(&with_encoder(SliceEncoderKind::Cbam)),
        base + 11_264 + 4 * 98
    );
    // The improved CBAM adds a tanh MLP with reduction 32 (C²/16 each: 5,632).
    assert_eq!(
        params(&with_encoder(SliceEncoderKind::ImprovedCbam)),
        base + 11_264 + 5_632 + 4 * 98
    );
    // LFA: stage 1 local 10→16→32, point 3→32; stage 2 local 74→32, point 67→32 (linear
    // weights + batch-norm γ, β) = 5,568; the PointNets' first layers see 3 + 64 inputs
    // (64 × (64 + 64 + 128 + 256) = 32,768 more weights).
    assert_eq!(params(&with_lfa()), base + 5_568 + 32_768);
    let text = render_info(&FConvNetConfig {
        model: with_lfa(),
        loss: LossConfig::default(),
    })
    .unwrap();
    assert!(text.contains("lfa stage 2"), "{text}");
    assert!(text.contains(&format!("\nparameters: {}\n", base + 5_568 + 32_768)));
    // The shipped SAF's widths: 368,900 short of the paper's count, 9.91% under it.
    assert!(
        text.ends_with(
            "paper: 3724013 (SAF, He et al., Sensors 2022, Tables 4-6); ours -368900 (-9.91%)"
        ),
        "{text}"
    );
}

/// The paper-size LFA (`LfaConfig::paper`): one shared layer per MLP, 128 channels each
/// in the first stage and 256 in the second, so 512 per point into the PointNets. Its
/// count by hand, where it lies (LFA itself and the PointNets' first layers), and the
/// paper's count within 5% (−0.20%).
#[test]
fn the_paper_size_lfa_is_within_five_percent_of_the_papers_count() {
    let base = 3_316_777;
    let layer = |c_in: usize, c_out: usize| c_in * c_out + 2 * c_out; // weights + γ, β
    let stage1 = layer(10, 128) + layer(3, 128);
    let stage2 = layer(10 + 256, 256) + layer(3 + 256, 256);
    let pointnet_inputs = 512 * (64 + 64 + 128 + 256);
    let config = ModelConfig {
        lfa: Some(LfaConfig::paper()),
        ..ModelConfig::car()
    };
    let n = params(&config);
    assert_eq!(n, base + stage1 + stage2 + pointnet_inputs);
    let model = FConvNet::new(&config, &Device::flex()).unwrap();
    let table = ParamTable::new(&model);
    assert_eq!(table.block(Block::Lfa), stage1 + stage2);
    let fconvnet = ParamTable::new(&FConvNet::new(&ModelConfig::car(), &Device::flex()).unwrap());
    assert_eq!(
        table.block(Block::PointNets) - fconvnet.block(Block::PointNets),
        pointnet_inputs
    );
    for block in [Block::Fcn, Block::Deconv, Block::Heads] {
        assert_eq!(table.block(block), fconvnet.block(block), "{block:?}");
    }
    let paper = published_parameters(&config).unwrap();
    let off = (n as f64 - paper.params as f64) / paper.params as f64;
    assert!(off.abs() < 0.05, "{n} against {}", paper.params);
    let text = render_info(&FConvNetConfig {
        model: config,
        loss: LossConfig::default(),
    })
    .unwrap();
    assert!(text.contains("over F-ConvNet"), "{text}");
    let diff = n as i64 - paper.params as i64;
    assert!(
        text.ends_with(&format!(
            "ours {diff:+} ({:+.2}%)",
            100.0 * diff as f64 / paper.params as f64
        )),
        "{text}"
    );
    // The tiny network has no published count.
    let tiny = ModelConfig {
        lfa: Some(LfaConfig::paper()),
        ..ModelConfig::tiny()
    };
    assert_eq!(published_parameters(&tiny), None);
}

fn tiny_variant(kind: SliceEncoderKind, lfa: bool, projection: bool) -> FConvNetConfig {
    let mut c = FConvNetConfig::tiny();
    c.model.slice_encoder = kind;
    if lfa {
        c.model.lfa = Some(LfaConfig {
            neighbours: 8,
            stages: vec![
                LfaStageConfig {
                    local: vec![8],
                    point: vec![8],
                },
                LfaStageConfig {
                    local: vec![8],
                    point: vec![8],
                },
            ],
            ..LfaConfig::default()
        });
    }
    if projection {
        c.loss.projection_weight = 0.1;
    }
    c
}

#[test]
fn every_variant_fits_a_tiny_batch() {
    for (kind, lfa, projection) in [
        (SliceEncoderKind::Cbam, false, false),
        (SliceEncoderKind::ImprovedCbam, false, false),
        (SliceEncoderKind::PointNet, true, true),
        (SliceEncoderKind::ImprovedCbam, true, true),
    ] {
        let config = tiny_variant(kind, lfa, projection);
        let gated = config.model.lfa.as_ref().map(|l| FConvNetConfig {
            model: ModelConfig {
                lfa: Some(LfaConfig {
                    feature_gate: LfaFeatureGate::Zero,
                    coordinate_init: CoordinateInit::Own,
                    ..l.clone()
                }),
                ..config.model.clone()
            },
            ..config.clone()
        });
        for config in std::iter::once(config).chain(gated) {
            let device = Device::flex().autodiff();
            device.seed(5);
            let mut model = FConvNet::new(&config.model, &device).unwrap();
            let spec = SyntheticSpec::tiny(4);
            let batch = if lfa {
                lfa_batch(&spec, 3, 4)
            } else {
                synthetic_batch(&spec, 3)
            };
            let inputs = model.inputs(&batch, &device).unwrap();
            let targets = LossTargets::new(&batch, &config.model, &config.loss, &device).unwrap();
            let mut optim = AdamConfig::new().init();
            let mut losses = vec![];
            for _ in 0..30 {
                let out = model.forward_inputs(&inputs);
                let loss = fconvnet_loss(&out, &targets, &config.loss).unwrap();
                if projection {
                    assert!(loss.components.projection > 0.0);
                } else {
                    assert_eq!(loss.components.projection, 0.0);
                }
                losses.push(loss.components.total);
                let grads = GradientsParams::from_grads(loss.total.backward(), &model);
                model = optim.step(3e-3, model, grads);
            }
            let (first, last) = (losses[0], *losses.last().unwrap());
            let gate = config.model.lfa.as_ref().map(|l| l.feature_gate);
            println!("{kind:?} lfa {gate:?} pl {projection}: {first} → {last}");
            assert!(
                last < 0.5 * first,
                "{kind:?} {gate:?}: loss {first} → {last}"
            );
            if gate == Some(LfaFeatureGate::Zero) {
                // The gate opened during training.
                let opened: f32 = model
                    .lfa
                    .as_ref()
                    .unwrap()
                    .gate
                    .as_ref()
                    .unwrap()
                    .val()
                    .abs()
                    .max()
                    .into_scalar();
                assert!(opened > 0.0, "{kind:?}: the gate stayed shut");
            }
        }
    }
}

#[test]
fn lfa_rejects_slices_that_use_dropped_points() {
    let config = tiny_variant(SliceEncoderKind::PointNet, true, false);
    let device = Device::flex();
    let model = FConvNet::new(&config.model, &device).unwrap();
    // All 128 points of the plain batch are sliced, but LFA keeps only 32 of them.
    let err = model
        .inputs(&synthetic_batch(&SyntheticSpec::tiny(2), 1), &device)
        .unwrap_err()
        .to_string();
    assert!(err.contains("sliced_points = 32"), "{err}");
}

#[test]
fn projection_term_matches_a_hand_computation() {
    let device = Device::flex();
    // A KITTI-like pinhole: u = 700 x / z + 600, v = 700 y / z + 180.
    let m = [
        700.0f32, 0.0, 600.0, 0.0, 0.0, 700.0, 180.0, 0.0, 0.0, 0.0, 1.0, 0.0,
    ];
    let gt_corners = box_corners([1.0, 1.0, 20.0], 0.3, [3.9, 1.6, 1.5]);
    let pred = ([1.3f32, 0.9, 21.0], 0.2f32, [4.2f32, 1.7, 1.4]);
    let gt = projected_box(&gt_corners, &m).unwrap();
    let p = projected_box(&box_corners(pred.0, pred.1, pred.2), &m).unwrap();
    let huber = |e: f32| {
        if e.abs() <= 1.0 {
            0.5 * e * e
        } else {
            e.abs() - 0.5
        }
    };
    let want = huber((p[0] - gt[0]) / gt[2])
        + huber((p[1] - gt[1]) / gt[3])
        + huber((p[2] / gt[2]).ln())
        + huber((p[3] / gt[3]).ln());
    let corners = box_corners_tensor(
        Tensor::from_data(TensorData::new(pred.0.to_vec(), [1, 3]), &device),
        Tensor::from_data(TensorData::new(vec![pred.1], [1, 1]), &device),
        Tensor::from_data(TensorData::new(pred.2.to_vec(), [1, 3]), &device),
    );
    let got = projection_loss(
        corners,
        Tensor::from_data(TensorData::new(m.to_vec(), [1, 3, 4]), &device),
        Tensor::from_data(TensorData::new(gt.to_vec(), [1, 4]), &device),
    )
    .into_scalar::<f32>();
    assert!(want > 0.0);
    assert!((got - want).abs() < 1e-5 * want.max(1.0), "{got} vs {want}");
    // Behind the camera: no 2D box.
    assert!(projected_box(&box_corners([0.0, 0.0, -5.0], 0.0, [1.0; 3]), &m).is_none());
}

#[test]
fn checkpoints_remember_the_variant() {
    let dir = std::env::temp_dir().join(format!("fusiondet-variant-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("fcam.bpk");
    let config = tiny_variant(SliceEncoderKind::ImprovedCbam, true, false).model;
    let device = Device::flex();
    let model = FConvNet::new(&config, &device).unwrap();
    save_checkpoint(&model, &path).unwrap();
    assert!(load_checkpoint(&config, &path, &device).is_ok());
    let plain = ModelConfig {
        lfa: None,
        ..config.clone()
    };
    let err = load_checkpoint(&plain, &path, &device)
        .unwrap_err()
        .to_string();
    assert!(err.contains("lfa"), "{err}");
    // A gated model keeps its gate; a config without the gate refuses its file, and the
    // gated config refuses an ungated file.
    let gated_config = ModelConfig {
        lfa: Some(LfaConfig {
            feature_gate: LfaFeatureGate::Zero,
            ..config.lfa.clone().unwrap()
        }),
        ..config.clone()
    };
    let mut gated = FConvNet::new(&gated_config, &device).unwrap();
    let c = gated_config.lfa.as_ref().unwrap().out_channels();
    let values: Vec<f32> = (0..c).map(|i| i as f32 * 0.01 - 0.1).collect();
    gated.lfa.as_mut().unwrap().gate = Some(Param::from_tensor(Tensor::from_data(
        TensorData::new(values.clone(), [c]),
        &device,
    )));
    let gated_path = dir.join("gated.bpk");
    save_checkpoint(&gated, &gated_path).unwrap();
    let back = load_checkpoint(&gated_config, &gated_path, &device).unwrap();
    let gate = back.lfa.unwrap().gate.unwrap().val();
    assert_eq!(gate.try_into_vec_as::<f32>().unwrap(), values);
    let err = load_checkpoint(&config, &gated_path, &device)
        .unwrap_err()
        .to_string();
    assert!(err.contains("feature_gate"), "{err}");
    let err = load_checkpoint(&gated_config, &path, &device)
        .unwrap_err()
        .to_string();
    assert!(err.contains("feature_gate"), "{err}");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn ground_truth_behind_the_camera_is_left_out_of_the_projection_term() {
    let config = tiny_variant(SliceEncoderKind::PointNet, false, true);
    let device = Device::flex();
    let model = FConvNet::new(&config.model, &device).unwrap();
    let mut batch = synthetic_batch(&SyntheticSpec::tiny(3), 9);
    // Frustum 0 looks backwards: every corner of its ground truth is behind the camera.
    batch.image_projection[8..12].copy_from_slice(&[0.0, 0.0, -1.0, 0.0]);
    let targets = LossTargets::new(&batch, &config.model, &config.loss, &device).unwrap();
    let out = model.forward(&batch, &device).unwrap();
    let with_one_behind = fconvnet_loss(&out, &targets, &config.loss).unwrap();
    assert!(with_one_behind.components.projection.is_finite());
    // All of them behind: the term is zero, the rest of the loss unchanged.
    for f in 0..3 {
        batch.image_projection[f * 12 + 8..f * 12 + 12].copy_from_slice(&[0.0, 0.0, -1.0, 0.0]);
    }
    let targets = LossTargets::new(&batch, &config.model, &config.loss, &device).unwrap();
    let none = fconvnet_loss(&out, &targets, &config.loss).unwrap();
    assert_eq!(none.components.projection, 0.0);
    assert_eq!(none.components.corner, with_one_behind.components.corner);
}
