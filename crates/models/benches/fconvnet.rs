//! F-ConvNet Car benchmarks on the flex CPU backend:
//! inference for one frame (8 frustums) and its parts, SAF's local feature aggregation for
//! the same frame (host neighbour search and network), a training step for batch 32, and the
//! backend's matrix-multiply rate, the yardstick the step's rate is read against. Throughput
//! is in FLOPs (2 per multiply-add; a training step counted as 3 forward passes: the forward,
//! and the backward's input and weight gradients), so criterion's `thrpt` reads as FLOP/s.
//! Training's benchmarks run twice, with the custom flex operations that training takes
//! (`fusiondet_nn::ragged`) and with burn's generic operations (`…, generic ops`), so one run
//! shows both side by side.
//!
//! `cargo bench -p fusiondet-models --bench fconvnet`

use burn::optim::{AdamConfig, GradientsParams};
use burn::prelude::*;
use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use fusiondet_models::synthetic::{SyntheticSpec, synthetic_batch};
use fusiondet_models::*;
use std::hint::black_box;
use std::time::{Duration, Instant};

/// The binary's allocator and its option (`fusiondet_alloc`), so the figures are the
/// binary's: with glibc's, the step spends a fifth of its time in the kernel mapping and
/// zeroing pages.
#[global_allocator]
static ALLOCATOR: fusiondet_alloc::MiMalloc = fusiondet_alloc::MiMalloc;

/// Reads a tensor back so lazily executed work is finished inside the timing.
fn sync<const D: usize>(t: &Tensor<D>) -> f32 {
    t.try_to_vec_as::<f32>().unwrap()[0]
}

fn inference(c: &mut Criterion) {
    fusiondet_alloc::keep_freed_memory();
    let config = FConvNetConfig::car();
    let device = Device::flex();
    let model = FConvNet::new(&config.model, &device).unwrap().valid();
    let batch = synthetic_batch(&SyntheticSpec::car(8), 42);
    for (k, s) in batch.scales.iter().enumerate() {
        eprintln!(
            "scale {k}: {} slices × 8, {} pairs ({:.0} per frustum)",
            s.slices_per_frustum,
            s.pair_point.len(),
            s.pair_point.len() as f64 / 8.0
        );
    }
    let inputs = model.inputs(&batch, &device).unwrap();

    let mut g = c.benchmark_group("car_inference_b8");
    g.sample_size(20).measurement_time(Duration::from_secs(8));
    g.bench_function("frame_total (inputs + forward + decode)", |b| {
        b.iter(|| {
            let inputs = model.inputs(black_box(&batch), &device).unwrap();
            let out = model.forward_inputs(&inputs);
            decode(&out, &inputs, &config.model).unwrap()
        })
    });
    g.bench_function("inputs (host preprocessing)", |b| {
        b.iter(|| model.inputs(black_box(&batch), &device).unwrap())
    });
    g.bench_function("forward", |b| {
        b.iter(|| sync(&model.forward_inputs(&inputs).regression))
    });
    for k in 0..4 {
        g.bench_function(format!("pointnet scale {}", k + 1), |b| {
            b.iter(|| sync(&model.encoders[k].forward(&inputs.scales[k], None)))
        });
    }
    g.finish();
}

/// FCAM's forward (the improved CBAM after each slice PointNet's first layer) beside
/// F-ConvNet's on the same frame, both with batch norm folded as the binary runs them.
fn fcam_inference(c: &mut Criterion) {
    fusiondet_alloc::keep_freed_memory();
    let device = Device::flex();
    let batch = synthetic_batch(&SyntheticSpec::car(8), 42);
    let mut g = c.benchmark_group("fcam_vs_fconvnet_b8");
    g.sample_size(20).measurement_time(Duration::from_secs(8));
    for (name, encoder) in [
        ("fconvnet forward", SliceEncoderKind::PointNet),
        ("fcam forward", SliceEncoderKind::ImprovedCbam),
    ] {
        let mut config = FConvNetConfig::car();
        config.model.slice_encoder = encoder;
        config.model.attention.after_layers = vec![0];
        let mut model = FConvNet::new(&config.model, &device).unwrap().valid();
        model.fold_norms();
        let inputs = model.inputs(&batch, &device).unwrap();
        g.bench_function(name, |b| {
            b.iter(|| sync(&model.forward_inputs(&inputs).regression))
        });
    }
    g.finish();
}

/// SAF's LFA for one frame of 8 Car frustums of 4,096 points (its shipped stages): the
/// host-side index building (two k-nearest-neighbour searches per frustum) and the network.
fn saf_lfa(c: &mut Criterion) {
    fusiondet_alloc::keep_freed_memory();
    let device = Device::flex();
    let mut config = FConvNetConfig::car();
    let lfa_config = fusiondet_models::config::LfaConfig::default();
    config.model.lfa = Some(lfa_config.clone());
    let lfa = fusiondet_models::lfa::Lfa::new(&config.model, &lfa_config, &device);
    let mut spec = SyntheticSpec::car(8);
    spec.points_per_frustum = 4096;
    let batch = synthetic_batch(&spec, 42);
    let index = |points: &[f32]| {
        fusiondet_models::lfa::LfaInputs::new(points, 8, 4096, &lfa_config, &device).unwrap()
    };
    let inputs = index(&batch.points);
    let mut g = c.benchmark_group("saf_lfa_b8");
    g.sample_size(20).measurement_time(Duration::from_secs(8));
    g.bench_function("neighbour search (host)", |b| {
        b.iter(|| index(black_box(&batch.points)))
    });
    g.bench_function("forward", |b| b.iter(|| sync(&lfa.forward(&inputs))));
    // Training's LFA: forward and backward of its features' sum on the autodiff device,
    // with the custom operations and with burn's generic ones.
    let train_device = Device::flex().autodiff();
    let train_lfa = fusiondet_models::lfa::Lfa::new(&config.model, &lfa_config, &train_device);
    let train_inputs =
        fusiondet_models::lfa::LfaInputs::new(&batch.points, 8, 4096, &lfa_config, &train_device)
            .unwrap();
    for (name, custom) in [
        ("train forward + backward", true),
        ("train forward + backward, generic ops", false),
    ] {
        fusiondet_nn::ragged::set_custom_ops(custom);
        g.bench_function(name, |b| {
            b.iter(|| {
                let grads = train_lfa.forward(&train_inputs).sum().backward();
                let w = train_lfa.stages[0].local[0].linear.weight.val();
                sync(&w.grad(&grads).unwrap())
            })
        });
    }
    fusiondet_nn::ragged::set_custom_ops(true);
    g.finish();
}

fn train_step(c: &mut Criterion) {
    fusiondet_alloc::keep_freed_memory();
    let config = FConvNetConfig::car();
    let device = Device::flex().autodiff();
    let batch = synthetic_batch(&SyntheticSpec::car(32), 7);
    let mut model = Some(FConvNet::new(&config.model, &device).unwrap());
    let inputs = model.as_ref().unwrap().inputs(&batch, &device).unwrap();
    let targets = LossTargets::new(&batch, &config.model, &config.loss, &device).unwrap();
    let mut optim = AdamConfig::new().init();

    let macs = forward_macs(&config.model, &batch).unwrap();
    let step_flops = 3 * 2 * macs.total();
    eprintln!(
        "forward multiply-adds, batch 32: pointnets {:?}, fcn {}, heads {} (total {:.2} G); \
         training step ≈ {:.2} GFLOP",
        macs.pointnets,
        macs.fcn,
        macs.heads,
        macs.total() as f64 * 1e-9,
        step_flops as f64 * 1e-9
    );
    let mut g = c.benchmark_group("car_train_b32");
    g.sample_size(10).measurement_time(Duration::from_secs(30));
    g.throughput(Throughput::Elements(step_flops));
    // Each step twice: with the custom flex operations (`fusiondet_nn::ragged`, what
    // training runs) and with burn's generic operations (the path before them), side by
    // side in one run.
    let mut step = || {
        let m = model.take().unwrap();
        let loss = fconvnet_loss(&m.forward_inputs(&inputs), &targets, &config.loss).unwrap();
        let grads = GradientsParams::from_grads(loss.total.backward(), &m);
        model = Some(optim.step(1e-3, m, grads));
        loss.components.total
    };
    for (name, custom) in [
        ("train_step (forward + loss + backward + adam)", true),
        ("train_step, generic ops", false),
    ] {
        fusiondet_nn::ragged::set_custom_ops(custom);
        g.bench_function(name, |b| b.iter(&mut step));
    }
    fusiondet_nn::ragged::set_custom_ops(true);
    // The binary runs its steps on a worker of a rayon pool (`pipeline::compute_pool`),
    // where flex's parallel loops start in the pool instead of parking the caller.
    let pool = worker_pool();
    g.bench_function("train_step on a pool worker (as the binary)", |b| {
        b.iter(|| pool.install(&mut step))
    });
    for (name, custom) in [
        ("forward + loss (autodiff graph)", true),
        ("forward + loss (autodiff graph), generic ops", false),
    ] {
        fusiondet_nn::ragged::set_custom_ops(custom);
        // Timed: the forward pass and the loss. Untimed: a backward pass, which releases the
        // graph (autodiff keeps a graph nobody differentiated, and 30 of them at batch 32 ran
        // this machine out of memory).
        g.bench_function(name, |b| {
            b.iter_custom(|iterations| {
                let m = model.as_ref().unwrap();
                let mut timed = Duration::ZERO;
                for _ in 0..iterations {
                    let start = Instant::now();
                    let loss =
                        fconvnet_loss(&m.forward_inputs(&inputs), &targets, &config.loss).unwrap();
                    black_box(loss.components.total);
                    timed += start.elapsed();
                    drop(loss.total.backward());
                }
                timed
            })
        });
    }
    fusiondet_nn::ragged::set_custom_ops(true);
    g.finish();
}

/// A rayon pool of the global pool's size, as `pipeline::compute_pool` builds it.
fn worker_pool() -> rayon::ThreadPool {
    rayon::ThreadPoolBuilder::new()
        .num_threads(rayon::current_num_threads())
        .build()
        .unwrap()
}

/// The backend's f32 matrix product on all threads: a square one and the shape of the
/// scale-4 PointNet's widest layer over a frame (about 8,000 (point, sub-frustum) pairs × 256 → 512).
fn matmul_rate(c: &mut Criterion) {
    fusiondet_alloc::keep_freed_memory();
    let device = Device::flex();
    let mut g = c.benchmark_group("flex_matmul");
    g.sample_size(10).measurement_time(Duration::from_secs(10));
    for (name, [m, k, n]) in [
        ("1024x1024x1024", [1024, 1024, 1024]),
        ("pointnet 8192x256x512", [8192, 256, 512]),
    ] {
        let a = Tensor::<2>::random([m, k], burn::tensor::Distribution::Default, &device);
        let b = Tensor::<2>::random([k, n], burn::tensor::Distribution::Default, &device);
        g.throughput(Throughput::Elements(2 * (m * k * n) as u64));
        g.bench_function(name, |bench| {
            bench.iter(|| sync(&a.clone().matmul(b.clone())))
        });
    }
    let pool = worker_pool();
    let a = Tensor::<2>::random([1024, 1024], burn::tensor::Distribution::Default, &device);
    let b = Tensor::<2>::random([1024, 1024], burn::tensor::Distribution::Default, &device);
    g.throughput(Throughput::Elements(2 * 1024 * 1024 * 1024));
    g.bench_function("1024x1024x1024 on a pool worker", |bench| {
        bench.iter(|| pool.install(|| sync(&a.clone().matmul(b.clone()))))
    });
    g.finish();
}

/// Max over the middle axis of [groups, width, C], the ragged max-pool's and LFA's shape:
/// burn-flex's reduction, the same after moving the axis last, and the host path that
/// inference takes (`fusiondet_nn::host_max`).
fn middle_max(c: &mut Criterion) {
    fusiondet_alloc::keep_freed_memory();
    let device = Device::flex();
    let mut g = c.benchmark_group("middle_max");
    g.sample_size(20).measurement_time(Duration::from_secs(5));
    for [n, w, ch] in [[16384, 16, 32], [8192, 16, 32], [2000, 64, 256]] {
        let x = Tensor::<3>::random([n, w, ch], burn::tensor::Distribution::Default, &device);
        // Each variant gets a tensor of its own, as in the network (the host path reads a
        // uniquely owned buffer in place).
        let own = || x.clone().add_scalar(0.0);
        let batched = criterion::BatchSize::LargeInput;
        g.bench_function(format!("max_dim(1) {n}x{w}x{ch}"), |b| {
            b.iter_batched(own, |t| sync(&t.max_dim(1)), batched)
        });
        g.bench_function(format!("permute+max_dim(2) {n}x{w}x{ch}"), |b| {
            b.iter_batched(own, |t| sync(&t.permute([0, 2, 1]).max_dim(2)), batched)
        });
        g.bench_function(format!("host blocks_max {n}x{w}x{ch}"), |b| {
            b.iter_batched(
                own,
                |t| {
                    let rows = t.reshape([n * w, ch]);
                    sync(&fusiondet_nn::host_max::blocks_max(rows, w))
                },
                batched,
            )
        });
    }
    g.finish();
}

criterion_group!(
    benches,
    middle_max,
    inference,
    fcam_inference,
    saf_lfa,
    train_step,
    matmul_rate
);
criterion_main!(benches);
