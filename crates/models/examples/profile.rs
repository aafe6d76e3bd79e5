//! Where the time goes in the Car network on this machine: per-stage wall and process CPU
//! time for one frame's inference (8 frustums) and one training step (batch 32).
//!
//! `cargo run --release -p fusiondet-models --example profile [frustums] [train_batch]`
//!
//! CPU time (all threads) next to wall time shows how well the stage uses the cores and
//! keeps the numbers readable when other processes share the machine.

use burn::optim::{AdamConfig, GradientsParams};
use burn::prelude::*;
use fusiondet_models::synthetic::{SyntheticSpec, synthetic_batch};
use fusiondet_models::*;
use std::time::Instant;

/// Process CPU time (user + system, all threads) in seconds, from /proc/self/stat.
fn cpu_seconds() -> f64 {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    let fields: Vec<&str> = stat
        .rsplit(')')
        .next()
        .unwrap_or("")
        .split_whitespace()
        .collect();
    let ticks: f64 = fields.get(11).and_then(|v| v.parse().ok()).unwrap_or(0.0)
        + fields.get(12).and_then(|v| v.parse().ok()).unwrap_or(0.0);
    ticks / 100.0
}

fn sync<const D: usize>(t: &Tensor<D>) {
    let _ = t.try_to_vec_as::<f32>().unwrap();
}

/// Runs `f` `n` times after one warm-up; prints mean wall and CPU milliseconds.
fn stage<R>(name: &str, n: usize, mut f: impl FnMut() -> R) -> R {
    let _ = f();
    let (t, c) = (Instant::now(), cpu_seconds());
    let mut out = None;
    for _ in 0..n {
        out = Some(f());
    }
    let wall = t.elapsed().as_secs_f64() * 1e3 / n as f64;
    let cpu = (cpu_seconds() - c) * 1e3 / n as f64;
    println!("{name:<44} wall {wall:9.1} ms   cpu {cpu:9.1} ms");
    out.unwrap()
}

fn main() {
    let args: Vec<usize> = std::env::args()
        .skip(1)
        .filter_map(|a| a.parse().ok())
        .collect();
    let frustums = args.first().copied().unwrap_or(8);
    let train_batch = args.get(1).copied().unwrap_or(32);
    let config = FConvNetConfig::car();
    let device = Device::flex();
    let model = FConvNet::new(&config.model, &device).unwrap().valid();
    let batch = synthetic_batch(&SyntheticSpec::car(frustums), 42);
    let inputs = model.inputs(&batch, &device).unwrap();
    for (k, s) in inputs.scales.iter().enumerate() {
        println!(
            "scale {}: {} slices, {} pairs, {} rows gathered in {} buckets",
            k + 1,
            s.num_slices,
            s.num_pairs,
            s.pool.gathered_rows(),
            s.pool.buckets.len()
        );
    }
    println!("-- inference, {frustums} frustums");
    let n = 5;
    stage("inputs (host)", n, || {
        model.inputs(&batch, &device).unwrap()
    });
    let feats: Vec<Tensor<2>> = (0..4)
        .map(|k| {
            stage(&format!("pointnet scale {}", k + 1), n, || {
                let f = model.encoders[k].forward(&inputs.scales[k], None);
                sync(&f);
                f
            })
        })
        .collect();
    drop(feats);
    let out = stage("forward (all)", n, || {
        let o = model.forward_inputs(&inputs);
        sync(&o.regression);
        o
    });
    for round in 0..2 {
        stage(&format!("pointnets sequential (round {round})"), n, || {
            for k in 0..4 {
                sync(&model.encoders[k].forward(&inputs.scales[k], None));
            }
        });
        stage(
            &format!("pointnets on 4 threads (round {round})"),
            n,
            || {
                std::thread::scope(|s| {
                    let handles: Vec<_> = (0..4)
                        .map(|k| {
                            let (enc, scale) = (&model.encoders[k], &inputs.scales[k]);
                            s.spawn(move || sync(&enc.forward(scale, None)))
                        })
                        .collect();
                    handles.into_iter().for_each(|h| h.join().unwrap());
                })
            },
        );
    }
    stage("decode", n, || {
        decode(&out, &inputs, &config.model).unwrap()
    });
    stage("frame total (inputs + forward + decode)", n, || {
        let inputs = model.inputs(&batch, &device).unwrap();
        decode(&model.forward_inputs(&inputs), &inputs, &config.model).unwrap()
    });

    println!("-- training, batch {train_batch}");
    let ad = device.autodiff();
    let batch = synthetic_batch(&SyntheticSpec::car(train_batch), 7);
    let mut model = Some(FConvNet::new(&config.model, &ad).unwrap());
    let inputs = model.as_ref().unwrap().inputs(&batch, &ad).unwrap();
    let targets = LossTargets::new(&batch, &config.model, &config.loss, &ad).unwrap();
    let mut optim = AdamConfig::new().init();
    let n = 2;
    for k in 0..4 {
        stage(
            &format!("pointnet scale {} forward (autodiff)", k + 1),
            n,
            || {
                let f = model.as_ref().unwrap().encoders[k].forward(&inputs.scales[k], None);
                sync(&f);
            },
        );
    }
    stage("forward + loss", n, || {
        let m = model.as_ref().unwrap();
        fconvnet_loss(&m.forward_inputs(&inputs), &targets, &config.loss).unwrap()
    });
    stage("forward + loss + backward", n, || {
        let m = model.as_ref().unwrap();
        let loss = fconvnet_loss(&m.forward_inputs(&inputs), &targets, &config.loss).unwrap();
        loss.total.backward()
    });
    stage("train step (+ adam)", n, || {
        let m = model.take().unwrap();
        let loss = fconvnet_loss(&m.forward_inputs(&inputs), &targets, &config.loss).unwrap();
        let grads = GradientsParams::from_grads(loss.total.backward(), &m);
        model = Some(optim.step(1e-3, m, grads));
    });
}
