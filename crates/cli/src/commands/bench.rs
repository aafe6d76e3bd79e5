//! `fusiondet bench`: detection speed of a trained model — frames/s and the share of each
//! stage, medians over repeated runs on in-memory frames.

use crate::commands::detect::ModelOnSplit;
use fusiondet_pipeline::{BenchOptions, bench_detect};
use fusiondet_workflows::outln;

#[derive(clap::Args)]
pub struct BenchArgs {
    #[command(flatten)]
    pub input: ModelOnSplit,
    /// Timed runs after one warm-up run.
    #[arg(long, default_value_t = 5)]
    pub repeats: usize,
    /// Use at most this many frames of the split (0 = all).
    #[arg(long, default_value_t = 0)]
    pub max_frames: usize,
    /// Print the speed only: skip the device's arithmetic probes that follow it (matrix-product
    /// precision, repeated-row additions, training's batch norm, the sparse convolution's
    /// gradients), which take seconds of a lent GPU for every bench that repeats them.
    #[arg(long)]
    pub no_probes: bool,
}

/// The most timed runs `bench` takes (a median of a thousand is as good as of more).
const MAX_REPEATS: usize = 1000;

pub fn run(args: BenchArgs) -> anyhow::Result<()> {
    // Each run's times are kept: a count past this would only exhaust memory.
    if !(1..=MAX_REPEATS).contains(&args.repeats) {
        anyhow::bail!(
            "--repeats must be in 1..={MAX_REPEATS}, got {}",
            args.repeats
        );
    }
    let config = args.input.experiment_config()?;
    super::data_root::check_root("--data", &args.input.data)?;
    let name = config.name.clone();
    let kind = config.kind();
    let input = args.input;
    let device = input.device;
    let bench = bench_detect(&BenchOptions {
        config,
        checkpoint: input.checkpoint,
        data_dir: input.data,
        split: input.split,
        detections: input.detections,
        depth_dir: input.depth_dir,
        repeats: args.repeats,
        max_frames: args.max_frames,
        device: input.device,
    })?;
    outln!("{name}: {bench}");
    if kind == fusiondet_models::DetectorKind::Frustum {
        // The yardstick of a frame with 8 objects in view (KITTI's average is about 8).
        outln!(
            "  at 8 frustums a frame: {:.2} frames/s",
            bench.inputs_per_second() / 8.0
        );
    }
    if args.no_probes {
        return Ok(());
    }
    // Why a device's boxes may part from the CPU's by more than float noise.
    let error = fusiondet_pipeline::matmul_precision::matmul_relative_error(&device.device());
    outln!(
        "  f32 matrix product on this device ({side}×{side}): largest error {error:.1e} of its \
         terms' magnitude (unit roundoff: f32 6.0e-8, TF32 4.9e-4)",
        side = fusiondet_pipeline::matmul_precision::PROBE_SIDE
    );
    // Whether gathers that read rows more than once get their gradients right here.
    let added = fusiondet_pipeline::sparse_gradient_probe::repeated_row_addition(&device.device());
    outln!(
        "  repeated-row additions on this device (a gather's backward: 540027 rows into 20001, \
         {:.1} ms): largest difference from the CPU's, relative to its largest value: {:.1e}",
        added.seconds * 1e3,
        added.error
    );
    // What a training step's largest batch norm costs here, through the kernels and burn's
    // generic operations (GPUs only).
    use fusiondet_pipeline::{batch_norm_probe as norm, linear_probe as layer};
    if let Some(timing) = norm::batch_norm_timing(&device.device()) {
        print_paths(
            "training batch norm + ReLU",
            &format!("{} rows × {}", norm::PROBE_ROWS, norm::PROBE_CHANNELS),
            [
                "kernels",
                "burn's generic operations",
                "γ and β gradients'",
                "kernels",
                "burn's",
            ],
            &timing,
        );
    }
    // What a training step's widest point-wise layer costs here, its weight gradient summed
    // in chunks of rows and as one product (GPUs only).
    if let Some(timing) = layer::linear_timing(&device.device()) {
        print_paths(
            "training point-wise layer",
            &format!(
                "{} rows, {} → {}",
                norm::PROBE_ROWS,
                layer::PROBE_IN,
                layer::PROBE_OUT
            ),
            [
                "weight gradient in chunks",
                "as one product",
                "weight gradient's",
                "chunks",
                "one product",
            ],
            &timing,
        );
    }
    if kind != fusiondet_models::DetectorKind::Frustum {
        // Whether training on this device gets the sparse backbone's gradients right.
        let (layout, error) =
            fusiondet_pipeline::sparse_gradient_probe::in_the_devices_layout(&device.device());
        outln!(
            "  sparse convolution on this device ({sites} sites, 16 → 16, layout {}): largest \
             difference from the CPU's, relative to its largest value: output {:.1e}, input \
             gradient {:.1e}, weight gradient {:.1e}",
            layout.name(),
            error.output,
            error.input_gradient,
            error.weight_gradient,
            sites = fusiondet_pipeline::sparse_gradient_probe::PROBE_SITES,
        );
    }
    Ok(())
}

/// One line of a GPU probe timed both ways (`custom_op_probe`): `names` are the custom path's
/// and the generic path's names, the gradient compared, and the two paths' short names.
fn print_paths(
    what: &str,
    shape: &str,
    [custom, generic, gradient, custom_short, generic_short]: [&str; 5],
    timing: &fusiondet_pipeline::custom_op_probe::PathTiming,
) {
    outln!(
        "  {what} on this device ({shape}, forward and backward): {custom} {:.1} ms, {generic} \
         {:.1} ms; {gradient} largest difference from the CPU's, relative to its largest value: \
         {custom_short} {:.1e}, {generic_short} {:.1e}",
        timing.custom * 1e3,
        timing.generic * 1e3,
        timing.custom_error,
        timing.generic_error,
    );
}
