//! Detection speed: the detection pipeline run several times over the same in-memory
//! frames (reading files from disk is left out), with the median time of each stage.
//! `fusiondet bench` prints it; the ablation reports its frames/s the same way.

use crate::config::ExperimentConfig;
use crate::detect::{DetectInputs, SideInputs, StageTimes, load_detect_inputs};
use crate::error::{PipelineError, Result};
use std::fmt;
use std::path::PathBuf;
use std::time::Duration;

/// What to measure.
#[derive(Debug, Clone)]
pub struct BenchOptions {
    pub config: ExperimentConfig,
    pub checkpoint: PathBuf,
    pub data_dir: PathBuf,
    pub split: String,
    pub detections: Option<PathBuf>,
    /// DASANet: completed depth maps to read instead of completing.
    pub depth_dir: Option<PathBuf>,
    /// Timed runs (after one untimed warm-up run).
    pub repeats: usize,
    /// Use at most this many frames of the split (0 = all).
    pub max_frames: usize,
    /// Where the network runs.
    pub device: crate::device::ComputeDevice,
}

/// The timed runs of one model.
#[derive(Debug, Clone)]
pub struct DetectBench {
    pub frames: usize,
    /// Network inputs per run (frustums for the frustum family).
    pub samples: usize,
    pub runs: Vec<StageTimes>,
}

fn median(mut v: Vec<Duration>) -> Duration {
    v.sort();
    match v.len() {
        0 => Duration::ZERO,
        n if n % 2 == 1 => v[n / 2],
        n => (v[n / 2 - 1] + v[n / 2]) / 2,
    }
}

impl DetectBench {
    /// Median of each stage over the runs (load is not part of the runs).
    pub fn median(&self) -> StageTimes {
        let mut out = StageTimes::default();
        if let Some(first) = self.runs.first() {
            for (stage, _) in first.stages() {
                out.add(
                    stage,
                    median(self.runs.iter().map(|t| t.get(stage)).collect()),
                );
            }
            // Where stages overlapped, the median run's wall time says how much.
            if self.runs.iter().any(|t| t.overlap() > Duration::ZERO) {
                out.set_wall(self.median_total());
            }
        }
        out
    }

    /// Median total time of a run (frustums + network + decoding and NMS).
    pub fn median_total(&self) -> Duration {
        median(self.runs.iter().map(StageTimes::compute).collect())
    }

    pub fn frames_per_second(&self) -> f64 {
        self.frames as f64 / self.median_total().as_secs_f64().max(1e-9)
    }

    /// Network inputs (frustums, for the frustum family) per second of the median run.
    pub fn inputs_per_second(&self) -> f64 {
        self.samples as f64 / self.median_total().as_secs_f64().max(1e-9)
    }
}

impl fmt::Display for DetectBench {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let m = self.median();
        let total = self.median_total().as_secs_f64().max(1e-9);
        writeln!(
            f,
            "{} frames, {} network inputs ({:.1} per frame), {} timed runs (medians):",
            self.frames,
            self.samples,
            self.samples as f64 / self.frames.max(1) as f64,
            self.runs.len()
        )?;
        for &(name, d) in m.stages() {
            writeln!(
                f,
                "  {name:<36} {:>8.1} ms  {:>5.1}%",
                d.as_secs_f64() * 1e3,
                100.0 * d.as_secs_f64() / total
            )?;
        }
        let overlap = m.overlap().as_secs_f64();
        if overlap > 0.0 {
            writeln!(
                f,
                "  (frames prepared beside the network while it runs: the stages add \
                 up to {:.1} ms, {:.1} ms of it side by side)",
                m.busy().as_secs_f64() * 1e3,
                overlap * 1e3
            )?;
        }
        write!(
            f,
            "  total {:.1} ms per frame: {:.2} frames/s, {:.1} network inputs/s",
            1e3 * total / self.frames.max(1) as f64,
            self.frames_per_second(),
            self.inputs_per_second()
        )
    }
}

/// Loads the model and the frames once, runs detection `1 + repeats` times and keeps the
/// timings of all but the first.
pub fn bench_detect(options: &BenchOptions) -> Result<DetectBench> {
    let cfg = &options.config;
    let DetectInputs {
        detector,
        device,
        inputs,
    } = load_detect_inputs(
        cfg,
        &options.checkpoint,
        &options.data_dir,
        &options.split,
        SideInputs {
            detections: options.detections.as_deref(),
            depth_dir: options.depth_dir.as_deref(),
        },
        options.max_frames,
        options.device,
    )?;
    let mut runs = Vec::with_capacity(options.repeats);
    let mut samples = 0;
    for run in 0..=options.repeats {
        let mut timing = StageTimes::default();
        samples = detector.detect(&device, &inputs, &mut timing)?.samples;
        if run > 0 {
            runs.push(timing);
        }
    }
    if samples == 0 {
        // Timing a pipeline that never reached its network would report millions of frames/s.
        return Err(PipelineError::Invalid(format!(
            "the {} benchmarked frames gave the network nothing to run on (frustum family: no \
             2D detection of the configured classes; voxel families: no point in range), so \
             there is no speed to measure; bench a split whose frames have detections or points",
            inputs.frames()
        )));
    }
    Ok(DetectBench {
        frames: inputs.frames(),
        samples,
        runs,
    })
}

/// Frames/s of a finished detection run (disk reads left out), for one-off reports.
pub fn frames_per_second(frames: usize, timing: &StageTimes) -> f64 {
    frames as f64 / timing.compute().as_secs_f64().max(1e-9)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frustum::{STAGE_DECODE, STAGE_FRUSTUMS, STAGE_NETWORK};

    fn ms(v: u64) -> Duration {
        Duration::from_millis(v)
    }

    #[test]
    fn medians_and_rates() {
        let run = |a, b, c| {
            let mut t = StageTimes::default();
            t.load = ms(999);
            t.add(STAGE_FRUSTUMS, ms(a));
            t.add(STAGE_NETWORK, ms(b));
            t.add(STAGE_DECODE, ms(c));
            t
        };
        let bench = DetectBench {
            frames: 10,
            samples: 80,
            runs: vec![run(100, 900, 10), run(300, 700, 30), run(200, 800, 20)],
        };
        assert_eq!(bench.median().get(STAGE_NETWORK), ms(800));
        assert_eq!(bench.median_total(), ms(1020));
        assert!((bench.frames_per_second() - 10.0 / 1.02).abs() < 1e-9);
        let text = bench.to_string();
        assert!(text.contains("78.4%"), "{text}");
        assert!(text.contains("9.80 frames/s"), "{text}");
        assert_eq!(median(vec![ms(1), ms(3)]), ms(2));
    }
}
