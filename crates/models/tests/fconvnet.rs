//! Network, loss, decoding and checkpoint tests (one binary: burn links slowly).

use burn::module::Module;
use burn::optim::{AdamConfig, GradientsParams};
use burn::prelude::*;
use fusiondet_frustum::BoxCoder;
use fusiondet_frustum::FrustumBatch;
use fusiondet_models::boxes::box_corners;
use fusiondet_models::inputs::conv3_output_len;
use fusiondet_models::loss::{box_corners_tensor, focal_loss};
use fusiondet_models::synthetic::{SyntheticSpec, synthetic_batch};
use fusiondet_models::*;

/// burn's flex backend draws every random tensor (weight initialisation included) from one
/// process-wide generator, seeded from the operating system unless `seed` is called. Tests
/// that draw random numbers hold this lock and seed first, so that each sees the same
/// numbers on every run whatever runs beside it.
static RANDOM_DRAWS: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn seeded(device: &Device, seed: u64) -> std::sync::MutexGuard<'static, ()> {
    let guard = RANDOM_DRAWS
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner());
    device.seed(seed);
    guard
}

fn vec_of<const D: usize>(t: &Tensor<D>) -> Vec<f32> {
    t.try_to_vec_as::<f32>().unwrap()
}

fn grad<const D: usize>(param: &Tensor<D>, grads: &burn::tensor::Gradients) -> Vec<f32> {
    vec_of(&param.grad(grads).expect("a gradient"))
}

fn assert_close(a: &[f32], b: &[f32], tol: f32, what: &str) {
    assert_eq!(a.len(), b.len(), "{what}: lengths");
    let scale = b.iter().fold(0f32, |m, v| m.max(v.abs())).max(1e-6);
    let worst = a
        .iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0f32, f32::max);
    assert!(
        worst <= tol * scale,
        "{what}: max |diff| {worst} > {tol} × {scale}"
    );
}

/// A synthetic batch with every fifth slice of every scale emptied.
fn batch_with_empty_slices(spec: &SyntheticSpec, seed: u64) -> FrustumBatch {
    let mut batch = synthetic_batch(spec, seed);
    for scale in &mut batch.scales {
        let keep: Vec<bool> = scale.pair_slice.iter().map(|s| s % 5 != 2).collect();
        let mut it = keep.iter();
        scale.pair_point.retain(|_| *it.next().unwrap());
        let mut it = keep.iter();
        scale.pair_slice.retain(|_| *it.next().unwrap());
    }
    batch
}

#[test]
fn stride_two_convolutions_give_the_published_lengths() {
    assert_eq!(conv3_output_len(280, 2), 140);
    assert_eq!(conv3_output_len(140, 2), 70);
    assert_eq!(conv3_output_len(70, 2), 35);
    assert_eq!(conv3_output_len(280, 1), 280);
}

#[test]
fn ragged_and_padded_pointnets_agree_in_outputs_and_gradients() {
    let config = ModelConfig::tiny();
    let device = Device::flex().autodiff();
    // Fixed draws: the max-pool sends each gradient to one pair, and for unlucky weights two
    // pairs can tie within the rounding by which the two forms' batch statistics differ
    // (about 1 weight draw in 300), which routes a gradient to a different pair.
    let _draws = seeded(&device, 7);
    let model = FConvNet::new(&config, &device).unwrap();
    let batch = batch_with_empty_slices(&SyntheticSpec::tiny(3), 7);
    let inputs = model.inputs(&batch, &device).unwrap();
    assert!(inputs.scales.iter().all(|s| s.num_pairs > 0));
    // Several pooling buckets, out of slice order, are exercised.
    assert!(
        inputs
            .scales
            .iter()
            .any(|s| s.pool.buckets.len() > 2 && s.pool.restore.is_some())
    );

    // Per-scale slice features, training mode (batch statistics over the real pairs).
    for (k, (enc, scale)) in model.encoders.iter().zip(&inputs.scales).enumerate() {
        let ragged = enc.forward(scale, None);
        let padded = enc.forward_padded(&scale.padded(&device));
        assert_eq!(ragged.dims(), padded.dims());
        assert_close(
            &vec_of(&ragged),
            &vec_of(&padded),
            1e-4,
            &format!("scale {k} features"),
        );
        // Empty slices give zeros.
        let v = vec_of(&ragged);
        let c = ragged.dims()[1];
        assert!(
            v[2 * c..3 * c].iter().all(|x| *x == 0.0),
            "slice 2 is empty at scale {k}"
        );
    }

    // Whole network and gradients of a random linear functional of its outputs.
    let ragged = model.forward_inputs(&inputs);
    let padded = model.forward_inputs_padded(&inputs);
    assert_close(
        &vec_of(&ragged.cls_logits),
        &vec_of(&padded.cls_logits),
        1e-4,
        "cls",
    );
    assert_close(
        &vec_of(&ragged.regression),
        &vec_of(&padded.regression),
        1e-4,
        "reg",
    );
    let w = Tensor::<3>::random(
        ragged.regression.dims(),
        burn::tensor::Distribution::Normal(0.0, 1.0),
        &device,
    );
    let g_ragged = (ragged.regression * w.clone()).sum().backward();
    let g_padded = (padded.regression * w).sum().backward();
    for (k, enc) in model.encoders.iter().enumerate() {
        let fusiondet_models::pointnet::SliceEncoder::PointNet(pn) = enc;
        let weight = pn.layers[0].linear.weight.val();
        let gamma = pn.layers.last().unwrap().norm.gamma.val();
        for (name, a, b) in [
            (
                "first linear weight",
                grad(&weight, &g_ragged),
                grad(&weight, &g_padded),
            ),
            (
                "last batch-norm gamma",
                grad(&gamma, &g_ragged),
                grad(&gamma, &g_padded),
            ),
        ] {
            assert!(
                a.iter().any(|x| *x != 0.0),
                "scale {k} {name}: zero gradient"
            );
            assert_close(&a, &b, 1e-3, &format!("scale {k} {name} gradient"));
        }
    }

    // Inference mode (running statistics) agrees as well.
    let valid = model.valid();
    let inputs = valid.inputs(&batch, &Device::flex()).unwrap();
    let a = valid.forward_inputs(&inputs);
    let b = valid.forward_inputs_padded(&inputs);
    assert_close(
        &vec_of(&a.regression),
        &vec_of(&b.regression),
        1e-4,
        "inference reg",
    );
}

#[test]
fn output_shapes_for_car_and_tiny() {
    let device = Device::flex();
    let _draws = seeded(&device, 1);
    for (config, spec, positions) in [
        (ModelConfig::car(), SyntheticSpec::car(2), 140),
        (ModelConfig::tiny(), SyntheticSpec::tiny(5), 12),
    ] {
        let model = FConvNet::new(&config, &device).unwrap().valid();
        let batch = synthetic_batch(&spec, 1);
        let out = model.forward(&batch, &device).unwrap();
        assert_eq!(out.cls_logits.dims(), [spec.batch_size, positions, 2]);
        assert_eq!(out.regression.dims(), [spec.batch_size, positions, 39]);
        assert!(vec_of(&out.regression).iter().all(|v| v.is_finite()));
    }
}

#[test]
fn car_parameter_count() {
    let device = Device::flex();
    let _draws = seeded(&device, 2);
    let model = FConvNet::new(&ModelConfig::car(), &device).unwrap();
    let table = ParamTable::new(&model);
    println!("{table}");
    let n = table.total;
    println!("Car parameters: {n}");
    assert!((n as f64 - 3.32e6).abs() / 3.32e6 < 0.01, "{n}");
    // The published implementation's layers (no bias before batch norm) exactly.
    assert_eq!(n, 3_316_777);
    assert_eq!(table.rows.iter().map(|r| r.params).sum::<usize>(), n);
    assert_eq!(table.row("pointnet scale 1"), Some(12_992));
    assert_eq!(table.row("head reg"), Some(768 * 39 + 39));
    assert_eq!(table.block(Block::Heads), 768 * 39 + 39 + 768 * 2 + 2);
    assert_eq!(table.block(Block::Lfa), 0);
    assert_eq!(Block::ALL.iter().map(|&b| table.block(b)).sum::<usize>(), n);
    let with_bias = ModelConfig {
        bias_before_norm: true,
        ..ModelConfig::car()
    };
    assert_eq!(
        info::trainable_params(&FConvNet::new(&with_bias, &device).unwrap()),
        3_322_409
    );
    assert_eq!(model.num_params(), 3_316_777 + 11_264); // burn also counts running statistics
    assert_eq!(table.buffers, 11_264);
    let text = render_info(&FConvNetConfig::car()).unwrap();
    assert!(text.contains("\nparameters: 3316777\n"), "{text}");
    // The paper's count beside ours, and no baseline column for the baseline itself.
    assert!(text.ends_with("; ours +0 (+0.00%)"), "{text}");
    assert!(!text.contains("over F-ConvNet"), "{text}");
}

#[test]
fn loss_decreases_when_overfitting_a_tiny_batch() {
    let config = FConvNetConfig::tiny();
    let device = Device::flex().autodiff();
    let _draws = seeded(&device, 3);
    let mut model = FConvNet::new(&config.model, &device).unwrap();
    let batch = synthetic_batch(&SyntheticSpec::tiny(4), 3);
    let inputs = model.inputs(&batch, &device).unwrap();
    let targets = LossTargets::new(&batch, &config.model, &config.loss, &device).unwrap();
    assert!(targets.num_positives() > 0);
    let mut optim = AdamConfig::new().init();
    let mut losses = vec![];
    for _ in 0..40 {
        let out = model.forward_inputs(&inputs);
        let loss = fconvnet_loss(&out, &targets, &config.loss).unwrap();
        losses.push(loss.components.total);
        let grads = GradientsParams::from_grads(loss.total.backward(), &model);
        model = optim.step(3e-3, model, grads);
    }
    let (first, last) = (losses[0], *losses.last().unwrap());
    println!("tiny overfit: {first} → {last}");
    assert!(last < 0.3 * first, "loss {first} → {last}: {losses:?}");
}

#[test]
fn focal_loss_matches_hand_computation() {
    let device = Device::flex();
    let logits = Tensor::<2>::from_data([[2.0f32, 0.0], [0.0, 1.0], [1.0, 1.0]], &device);
    let labels = Tensor::<2, Int>::from_data(TensorData::new(vec![1i64, 0, 1], [3, 1]), &device);
    let alpha = Tensor::<2>::from_data([[0.25f32], [0.75], [0.25]], &device);
    let got = focal_loss(logits, labels, alpha, 2.0, 2.0).into_scalar::<f32>();
    let fl = |p: f64, a: f64| -a * (1.0 - p).powi(2) * p.ln();
    let sig = |x: f64| 1.0 / (1.0 + (-x).exp());
    // Row 0: p(1) = σ(−2); row 1: p(0) = σ(−1); row 2: p(1) = ½.
    let want = (fl(sig(-2.0), 0.25) + fl(sig(-1.0), 0.75) + fl(0.5, 0.25)) / 2.0;
    assert!((got as f64 - want).abs() < 1e-6, "{got} vs {want}");
}

#[test]
fn corner_order_matches_the_geometry_crate() {
    let b = fusiondet_kitti::Box3d {
        h: 1.5,
        w: 1.6,
        l: 3.9,
        x: 2.0,
        y: 1.7,
        z: 25.0,
        ry: 0.4,
    };
    let want = fusiondet_geometry::corners(&b);
    // Geometric centre: the KITTI location is the bottom-face centre (y down).
    let got = box_corners([2.0, 1.7 - 0.75, 25.0], 0.4, [3.9, 1.6, 1.5]);
    for k in 0..8 {
        for d in 0..3 {
            assert!(
                (got[k][d] as f64 - want[k][d]).abs() < 1e-5,
                "corner {k}: {got:?} vs {want:?}"
            );
        }
    }
    let device = Device::flex();
    let t = box_corners_tensor(
        Tensor::from_data([[2.0f32, 0.95, 25.0]], &device),
        Tensor::from_data([[0.4f32]], &device),
        Tensor::from_data([[3.9f32, 1.6, 1.5]], &device),
    );
    let flat: Vec<f32> = got.iter().flatten().copied().collect();
    assert_close(&vec_of(&t), &flat, 1e-6, "tensor corners");
}

/// One frustum, one output position (index 0) labelled positive, the rest negative.
struct LossCase {
    batch: FrustumBatch,
    center: [f32; 3],
    heading: f32,
    size: [f32; 3],
    residual: [f32; 3],
}

fn loss_case() -> LossCase {
    let mut batch = synthetic_batch(&SyntheticSpec::tiny(1), 11);
    let p = batch.scales[1].slices_per_frustum;
    let pc: [f32; 3] = batch.scales[1].slice_centers[0..3].try_into().unwrap();
    let center = [pc[0] + 0.2, pc[1] + 0.9, pc[2] + 0.5];
    let heading = 0.3;
    let mean = BoxCoder::kitti().mean_sizes_f32()[0];
    let residual = [0.05, -0.02, 0.1];
    let size: [f32; 3] = std::array::from_fn(|k| mean[k] * (1.0 + residual[k]));
    let (bin, res) = BoxCoder::kitti().heading_to_bin_f32(heading);
    let t = batch.targets.as_mut().unwrap();
    t.labels = (0..p).map(|j| if j == 0 { 1 } else { 0 }).collect();
    t.center = center.to_vec();
    t.heading_bin = vec![bin as i64];
    t.heading_residual = vec![res];
    t.size_cluster = vec![0];
    t.size_residual = residual.to_vec();
    t.corners = box_corners(center, heading, size)
        .iter()
        .flatten()
        .copied()
        .collect();
    LossCase {
        batch,
        center,
        heading,
        size,
        residual,
    }
}

/// Network output for `case` whose position 0 predicts centre + `dc`, heading residual
/// (normalised) `hres`, size residual `sres` of cluster 0; all scores zero.
fn crafted_output(case: &LossCase, dc: [f32; 3], hres: f32, sres: [f32; 3]) -> FConvNetOutput {
    let device = Device::flex();
    let p = case.batch.scales[1].slices_per_frustum;
    let pc = &case.batch.scales[1].slice_centers[0..3];
    let (bin, _) = BoxCoder::kitti().heading_to_bin_f32(case.heading);
    let mut reg = vec![0f32; p * 39];
    for d in 0..3 {
        reg[d] = case.center[d] + dc[d] - pc[d];
        reg[30 + d] = sres[d];
    }
    reg[3 + 12 + bin] = hres;
    FConvNetOutput {
        cls_logits: Tensor::zeros([1, p, 2], &device),
        regression: Tensor::from_data(TensorData::new(reg, [1, p, 39]), &device),
    }
}

fn huber(e: f64, delta: f64) -> f64 {
    let a = e.abs();
    let q = a.min(delta);
    0.5 * q * q + delta * (a - q)
}

#[test]
fn loss_components_match_hand_computation() {
    let case = loss_case();
    let config = FConvNetConfig::tiny();
    let device = Device::flex();
    let targets = LossTargets::new(&case.batch, &config.model, &config.loss, &device).unwrap();
    let p = case.batch.scales[1].slices_per_frustum as f64;
    let bin_half = std::f64::consts::PI / 12.0;
    let (_, res) = BoxCoder::kitti().heading_to_bin_f32(case.heading);
    let res_norm = res as f64 / bin_half;
    let fl = |pt: f64, a: f64| -a * (1.0 - pt).powi(2) * pt.ln();
    // All logits zero: p = ½ everywhere; one positive (α ¼), p − 1 negatives (α ¾).
    let cls = fl(0.5, 0.25) + (p - 1.0) * fl(0.5, 0.75);
    let ce = |n: f64| n.ln();

    // A: centre off by (0.3, 0, 0.4), box otherwise exact → every corner 0.5 m off.
    let out = crafted_output(&case, [0.3, 0.0, 0.4], res_norm as f32, case.residual);
    let c = fconvnet_loss(&out, &targets, &config.loss)
        .unwrap()
        .components;
    let close =
        |a: f32, b: f64, what: &str| assert!((a as f64 - b).abs() < 1e-4, "{what}: {a} vs {b}");
    close(c.cls, cls, "focal");
    close(c.center, huber(0.5, 3.0), "centre");
    close(c.heading_cls, ce(12.0), "heading cls");
    close(c.size_cls, ce(3.0), "size cls");
    close(c.heading_res, 0.0, "heading res");
    close(c.size_res, 0.0, "size res");
    close(c.corner, huber(0.5, 1.0), "corner");
    let total = cls + huber(0.5, 3.0) + ce(12.0) + ce(3.0) + 10.0 * huber(0.5, 1.0);
    close(c.total, total, "total");
    assert_eq!(c.num_positives, 1);

    // B: heading off by exactly π (normalised residual + 12 half-bins): the flipped twin
    // matches, so the corner loss vanishes while the heading residual loss is large.
    let out = crafted_output(&case, [0.0; 3], res_norm as f32 + 12.0, case.residual);
    let c = fconvnet_loss(&out, &targets, &config.loss)
        .unwrap()
        .components;
    close(c.corner, 0.0, "corner of the flipped box");
    close(c.heading_res, huber(12.0, 1.0), "heading res");
    close(c.center, huber(0.0, 3.0), "centre");

    // C: size residual off by (0.3, 0.4, 0) → residual distance 0.5; corners from the host helper.
    let sres = [
        case.residual[0] + 0.3,
        case.residual[1] + 0.4,
        case.residual[2],
    ];
    let out = crafted_output(&case, [0.0; 3], res_norm as f32, sres);
    let c = fconvnet_loss(&out, &targets, &config.loss)
        .unwrap()
        .components;
    close(c.size_res, huber(0.5, 1.0), "size res");
    let mean = BoxCoder::kitti().mean_sizes_f32()[0];
    let pred_size: [f32; 3] = std::array::from_fn(|k| mean[k] * (1.0 + sres[k]));
    let (a, b) = (
        box_corners(case.center, case.heading, pred_size),
        box_corners(case.center, case.heading, case.size),
    );
    let mean_dist = (0..8)
        .map(|k| {
            (0..3)
                .map(|d| ((a[k][d] - b[k][d]) as f64).powi(2))
                .sum::<f64>()
                .sqrt()
        })
        .sum::<f64>()
        / 8.0;
    close(c.corner, huber(mean_dist, 1.0), "corner of the resized box");
}

#[test]
fn non_finite_loss_is_a_typed_error() {
    let case = loss_case();
    let config = FConvNetConfig::tiny();
    let device = Device::flex();
    let targets = LossTargets::new(&case.batch, &config.model, &config.loss, &device).unwrap();
    let mut out = crafted_output(&case, [0.0; 3], 0.0, case.residual);
    let p = out.regression.dims()[1];
    let mut reg = vec_of(&out.regression);
    reg[1] = f32::NAN;
    out.regression = Tensor::from_data(TensorData::new(reg, [1, p, 39]), &device);
    match fconvnet_loss(&out, &targets, &config.loss) {
        Err(ModelError::NonFiniteLoss { component, .. }) => assert_eq!(component, "center"),
        other => panic!("expected NonFiniteLoss, got {other:?}"),
    }
    let mut out = crafted_output(&case, [0.0; 3], 0.0, case.residual);
    out.cls_logits = Tensor::full([1, p, 2], f32::INFINITY, &device);
    let err = fconvnet_loss(&out, &targets, &config.loss).unwrap_err();
    assert!(
        matches!(
            err,
            ModelError::NonFiniteLoss {
                component: "cls",
                ..
            }
        ),
        "{err}"
    );
    assert!(err.to_string().contains("non-finite loss"));
}

#[test]
fn decode_picks_the_best_position() {
    let case = loss_case();
    let config = ModelConfig::tiny();
    let device = Device::flex();
    let inputs = BatchInputs::new(&case.batch, &config, &device).unwrap();
    let (_, res) = BoxCoder::kitti().heading_to_bin_f32(case.heading);
    let mut out = crafted_output(
        &case,
        [0.0; 3],
        res / (std::f32::consts::PI / 12.0),
        case.residual,
    );
    let p = inputs.positions;
    let mut cls = vec![0f32; p * 2];
    cls[1] = 2.0; // position 0: object logit 2 vs 0
    cls[7] = 1.0; // position 3: 1 vs 0
    out.cls_logits = Tensor::from_data(TensorData::new(cls, [1, p, 2]), &device);
    let mut reg = vec_of(&out.regression);
    let (bin, _) = BoxCoder::kitti().heading_to_bin_f32(case.heading);
    reg[3 + bin] = 5.0;
    reg[3 + 24] = 5.0;
    out.regression = Tensor::from_data(TensorData::new(reg, [1, p, 39]), &device);
    let pred = decode(&out, &inputs, &config).unwrap().remove(0);
    assert_eq!(pred.position, 0);
    assert!((pred.score - 1.0 / (1.0 + (-2f32).exp())).abs() < 1e-6);
    assert_eq!((pred.heading_bin, pred.size_cluster), (bin, 0));
    for d in 0..3 {
        assert!((pred.center[d] - case.center[d]).abs() < 1e-5);
        assert!((pred.size(&BoxCoder::kitti())[d] - case.size[d]).abs() < 1e-5);
    }
    assert!((pred.heading(&BoxCoder::kitti()) - case.heading).abs() < 1e-5);
}

#[test]
fn checkpoint_round_trip_and_config_mismatch() {
    let config = FConvNetConfig::tiny();
    let device = Device::flex().autodiff();
    let _draws = seeded(&device, 4);
    let mut model = FConvNet::new(&config.model, &device).unwrap();
    let batch = synthetic_batch(&SyntheticSpec::tiny(3), 5);
    // Two training steps so the weights and batch-norm running statistics leave their init.
    let inputs = model.inputs(&batch, &device).unwrap();
    let targets = LossTargets::new(&batch, &config.model, &config.loss, &device).unwrap();
    let mut optim = AdamConfig::new().init();
    for _ in 0..2 {
        let loss = fconvnet_loss(&model.forward_inputs(&inputs), &targets, &config.loss).unwrap();
        let grads = GradientsParams::from_grads(loss.total.backward(), &model);
        model = optim.step(1e-2, model, grads);
    }
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("fconvnet.bpk");
    save_checkpoint(&model, &path).unwrap();
    save_checkpoint(&model, &path).unwrap(); // replacing an existing checkpoint works
    let names: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(names.len(), 1, "stray files: {names:?}");

    let cpu = Device::flex();
    let original = model.valid();
    let loaded = load_checkpoint(&config.model, &path, &cpu).unwrap().valid();
    let inputs = original.inputs(&batch, &cpu).unwrap();
    let (a, b) = (
        original.forward_inputs(&inputs),
        loaded.forward_inputs(&inputs),
    );
    assert_eq!(vec_of(&a.cls_logits), vec_of(&b.cls_logits));
    assert_eq!(vec_of(&a.regression), vec_of(&b.regression));
    let fresh = FConvNet::new(&config.model, &cpu)
        .unwrap()
        .valid()
        .forward_inputs(&inputs);
    assert_ne!(vec_of(&fresh.regression), vec_of(&b.regression));
    assert_eq!(read_checkpoint_config(&path).unwrap(), config.model);

    // Other widths, and a same-shaped network with other size clusters, are refused.
    for other in [
        ModelConfig::car(),
        ModelConfig {
            size_clusters: vec![[4.0, 1.7, 1.5]; 3],
            ..ModelConfig::tiny()
        },
    ] {
        let err = load_checkpoint(&other, &path, &cpu).unwrap_err();
        assert!(matches!(err, ModelError::ConfigMismatch { .. }), "{err}");
        println!("{err}");
    }
    let err = load_checkpoint(&config.model, &dir.path().join("missing.bpk"), &cpu).unwrap_err();
    assert!(matches!(err, ModelError::Checkpoint { .. }), "{err}");
}

#[test]
fn batches_that_do_not_fit_are_rejected() {
    let config = ModelConfig::tiny();
    let device = Device::flex();
    let good = synthetic_batch(&SyntheticSpec::tiny(2), 1);
    assert!(BatchInputs::new(&good, &config, &device).is_ok());
    let mut bad = good.clone();
    bad.scales[2].slices_per_frustum += 1;
    assert!(matches!(
        BatchInputs::new(&bad, &config, &device),
        Err(ModelError::Batch(_))
    ));
    let mut bad = good.clone();
    bad.scales[0].pair_slice.reverse();
    assert!(matches!(
        BatchInputs::new(&bad, &config, &device),
        Err(ModelError::Batch(_))
    ));
    let mut bad = good.clone();
    bad.scales[0].max_points_per_slice = 1;
    assert!(matches!(
        BatchInputs::new(&bad, &config, &device),
        Err(ModelError::Batch(_))
    ));
    let mut bad = good;
    bad.targets = None;
    assert!(LossTargets::new(&bad, &config, &LossConfig::default(), &device).is_err());
}

#[test]
fn configuration_reads_from_toml() {
    let car = FConvNetConfig::car();
    assert_eq!(
        FConvNetConfig::from_toml_str(&car.to_toml_string()).unwrap(),
        car
    );
    let tiny = FConvNetConfig::tiny();
    assert_eq!(
        FConvNetConfig::from_toml_str(&tiny.to_toml_string()).unwrap(),
        tiny
    );
    assert_eq!(FConvNetConfig::from_toml_str("").unwrap(), car);
    let text = "[model]\nnum_heading_bins = 8\n[loss]\ncorner_weight = 5.0\n[train]\nepochs = 3\n";
    let c = FConvNetConfig::from_toml_str(text).unwrap();
    assert_eq!((c.model.num_heading_bins, c.loss.corner_weight), (8, 5.0));
    assert_eq!(c.model.regression_channels(), 3 + 16 + 12);
    assert!(FConvNetConfig::from_toml_str("[model]\nwidths = 3\n").is_err());
    assert!(FConvNetConfig::from_toml_str("[model]\nfcn_channels = [1, 2]\n").is_err());
}

#[test]
fn bundled_configuration_files_match_the_presets() {
    // The experiment files under the repository's configs/ carry [model] and [loss] tables.
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs");
    let car = FConvNetConfig::from_toml_file(&dir.join("fconvnet-car.toml")).unwrap();
    assert_eq!(car, FConvNetConfig::car());
    let tiny = FConvNetConfig::from_toml_file(&dir.join("tiny.toml")).unwrap();
    assert_eq!(tiny, FConvNetConfig::tiny());
}

#[test]
fn batch_tensors_and_the_model_can_move_between_threads() {
    fn send<T: Send + 'static>() {}
    send::<BatchInputs>();
    send::<LossTargets>();
    send::<FConvNet>();
    fn sync<T: Sync>() {}
    sync::<FConvNet>();
    sync::<BatchInputs>();
    send::<FConvNetOutput>();
}
