//! The training loop, generic over a detector family ([`TrainingTask`]): seeded
//! initialisation, Adam with step decay, a data thread that prepares the next batch while
//! the network trains on the current one, per-epoch checkpoints (weights and optimizer
//! state) and metrics, and exact resume. [`train`] picks the family from the
//! configuration's `[detector] kind`.

use crate::config::{ExperimentConfig, GradClipScope, OptimizerKind};
use crate::device::ComputeDevice;
use crate::error::{PipelineError, Result};
use crate::metrics_log::MetricsLog;
use crate::optimizer::TrainingOptimizer;
use crate::run_dir::{RunDir, RunLock, RunState};
use burn::module::Module;
use burn::optim::{GradientsParams, OptimizerRecord};
use burn::prelude::*;
use fusiondet_models::DetectorKind;
use serde_json::json;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// What `fusiondet train` was asked to do.
#[derive(Debug, Clone)]
pub struct TrainOptions {
    pub config: ExperimentConfig,
    pub data_dir: PathBuf,
    pub run_dir: PathBuf,
    pub resume: bool,
    /// Show a progress bar on stderr (and each epoch's line there). Each epoch is one line
    /// on stdout too where there is no bar or stdout is not a terminal, so a log file or a
    /// pipe shows the training advance.
    pub progress: bool,
    /// Where the network trains.
    pub device: ComputeDevice,
}

impl TrainOptions {
    /// A fresh run of `config` on `data_dir` into `run_dir`, on the CPU, without a progress
    /// bar.
    pub fn new(
        config: ExperimentConfig,
        data_dir: impl Into<PathBuf>,
        run_dir: impl Into<PathBuf>,
    ) -> TrainOptions {
        TrainOptions {
            config,
            data_dir: data_dir.into(),
            run_dir: run_dir.into(),
            resume: false,
            progress: false,
            device: ComputeDevice::default(),
        }
    }
}

/// What a finished `train` call did.
#[derive(Debug, Clone, PartialEq)]
pub struct TrainSummary {
    pub frames: usize,
    /// Training samples per epoch (frustums for the frustum family).
    pub samples: usize,
    /// What a sample is ("frustums", "frames").
    pub sample_noun: &'static str,
    pub epochs_run: usize,
    pub epochs_done: usize,
    pub final_loss: Option<f64>,
    pub model: PathBuf,
}

/// A batch's loss: the total to differentiate, and named components for the log (the
/// first is the total).
pub struct StepLoss {
    pub total: Tensor<1>,
    pub components: LossValues,
    /// Where the forward pass's seconds went, by named part (empty where a family does not
    /// split it): summed over an epoch into `metrics.jsonl`'s `step_seconds.forward_parts`.
    pub parts: ForwardParts,
}

/// A step's named loss values (the first the total): read already, or still on the network's
/// device, to be read in one transfer once the step's backward pass and update are queued.
/// Why: read term by term before the backward pass, a GPU step waited for its whole forward
/// pass, once a term, before a kernel of the backward pass was queued.
pub enum LossValues {
    Read(Vec<(&'static str, f32)>),
    OnDevice {
        names: Vec<&'static str>,
        /// [names] values, without autodiff (boxed: a tensor handle is large beside a `Vec`).
        values: Box<Tensor<1>>,
    },
}

impl LossValues {
    /// The values on the host (for values on the device, waiting for the work queued
    /// before them).
    pub fn read(self) -> Result<Vec<(&'static str, f32)>> {
        match self {
            LossValues::Read(values) => Ok(values),
            LossValues::OnDevice { names, values } => {
                let failed = |e: String| {
                    PipelineError::Invalid(format!(
                        "reading the loss back from the device failed: {e}"
                    ))
                };
                let values = values
                    .try_into_data()
                    .map_err(|e| failed(format!("{e:?}")))?
                    .convert::<f32>()
                    .try_into_vec::<f32>()
                    .map_err(|e| failed(format!("{e:?}")))?;
                Ok(names.into_iter().zip(values).collect())
            }
        }
    }
}

impl StepLoss {
    /// The sum of named (already weighted) terms, each logged under its name.
    pub fn from_terms(terms: Vec<(&'static str, Tensor<1>)>) -> StepLoss {
        let total = terms
            .iter()
            .map(|(_, t)| t.clone())
            .reduce(|a, b| a + b)
            .expect("a loss has at least one term");
        let names = std::iter::once("total")
            .chain(terms.iter().map(|(n, _)| *n))
            .collect();
        let values = Tensor::cat(
            std::iter::once(&total)
                .chain(terms.iter().map(|(_, t)| t))
                .map(|t| t.clone().inner())
                .collect(),
            0,
        );
        StepLoss {
            total,
            components: LossValues::OnDevice {
                names,
                values: Box::new(values),
            },
            parts: ForwardParts::default(),
        }
    }

    /// The same loss with the forward pass's parts timed (`parts`).
    pub fn with_parts(self, parts: ForwardParts) -> StepLoss {
        StepLoss { parts, ..self }
    }
}

/// Wall seconds of the named parts of one forward pass, in the order they first ran: what
/// a step's host work (proposals, RoI sampling, the RoI query) costs beside the network. On
/// a GPU a part that reads a tensor back also waits for the kernels queued before it, so a
/// part's seconds there are where the host waited, not where the device worked.
#[derive(Debug, Default, Clone, PartialEq)]
pub struct ForwardParts(Vec<(&'static str, f64)>);

impl ForwardParts {
    /// Runs `f`, adding its wall time to part `name`.
    pub fn time<T>(&mut self, name: &'static str, f: impl FnOnce() -> T) -> T {
        let started = Instant::now();
        let out = f();
        self.add(name, started.elapsed().as_secs_f64());
        out
    }

    /// Adds `seconds` to part `name`.
    pub fn add(&mut self, name: &'static str, seconds: f64) {
        match self.0.iter_mut().find(|(n, _)| *n == name) {
            Some((_, s)) => *s += seconds,
            None => self.0.push((name, seconds)),
        }
    }

    /// Every part with its seconds, in the order they first ran.
    pub fn parts(&self) -> &[(&'static str, f64)] {
        &self.0
    }

    /// Adds every part of `other` to this one's.
    fn absorb(&mut self, other: &ForwardParts) {
        for &(name, seconds) in &other.0 {
            self.add(name, seconds);
        }
    }
}

/// What the training loop needs from a detector family: its network, its prepared
/// training data, and its loss.
pub trait TrainingTask: Sync {
    type Model: Module;
    type Batch: Send;

    /// Frames the training samples come from.
    fn frames(&self) -> usize;
    /// Training samples in one epoch.
    fn samples(&self) -> usize;
    /// What a sample is called in the metrics log ("frustums").
    fn sample_noun(&self) -> &'static str;
    /// Said after the sample count when there are too few (e.g. what was skipped).
    fn sample_note(&self) -> String {
        String::new()
    }
    /// A freshly initialised network (weights from the configuration's seed alone).
    fn new_model(&self, device: &Device) -> Result<Self::Model>;
    fn load_model(&self, path: &Path, device: &Device) -> Result<Self::Model>;
    /// Writes the weights atomically.
    fn save_model(&self, model: &Self::Model, path: &Path) -> Result<()>;
    /// Writes what detection needs (`RUN_DIR/model.bpk`); training-only parts may be left
    /// out, since resuming reads the epoch checkpoints. Default: everything.
    fn save_inference_model(&self, model: &Self::Model, path: &Path) -> Result<()> {
        self.save_model(model, path)
    }
    /// The batches of epoch `epoch` (0-based) in training order; called on the data
    /// thread's behalf, so preparing a batch overlaps the previous step.
    fn epoch_batches(
        &self,
        epoch: usize,
    ) -> Box<dyn ExactSizeIterator<Item = Result<Self::Batch>> + Send + '_>;
    fn loss(&self, model: &Self::Model, batch: Self::Batch, device: &Device) -> Result<StepLoss>;
}

/// Trains the family named by the configuration. A training that fails before its first
/// epoch is committed removes the run directory it created, so that the corrected command
/// can be run again as it was (a resumed run's directory is never removed).
pub fn train(options: &TrainOptions) -> Result<TrainSummary> {
    let creates_run = !options.resume && !options.run_dir.exists();
    let result = match options.config.kind() {
        DetectorKind::Frustum => crate::frustum::train(options),
        DetectorKind::VoxelRcnn => crate::voxel_rcnn::train(options),
        DetectorKind::Dasanet => crate::dasanet::train(options),
    };
    if result.is_err() && creates_run && !RunDir::new(&options.run_dir).state().exists() {
        // Best effort: the error being returned is what the user needs to read.
        let _ = std::fs::remove_dir_all(&options.run_dir);
    }
    result
}

/// Set when the user asks a training to stop (Ctrl-C, through the binary's signal
/// handler): the loop stops at the next step and reports the last committed epoch.
pub static STOP_REQUESTED: std::sync::atomic::AtomicBool =
    std::sync::atomic::AtomicBool::new(false);

fn stop_requested() -> bool {
    STOP_REQUESTED.load(std::sync::atomic::Ordering::Relaxed)
}

fn bar(len: usize, enabled: bool) -> indicatif::ProgressBar {
    if !enabled {
        return indicatif::ProgressBar::hidden();
    }
    let bar = indicatif::ProgressBar::new(len as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{prefix} [{bar:30}] {pos}/{len} batches {elapsed}<{eta} {msg}",
        )
        .expect("valid template")
        .progress_chars("=> "),
    );
    bar
}

/// Draws a network's initial weights from `seed` alone, on the CPU whatever `device` the
/// network trains on (`init` builds it on the device it is given), then moves them there:
/// each burn backend has its own generator, so weights drawn on a GPU would differ from the
/// CPU's for the same seed, and a GPU training would not start where the CPU's does.
/// burn's initialisers draw from one process-wide generator, so seeding and drawing happen
/// under a lock: two runs in one process (tests, ablations) cannot interleave draws.
/// Its parameter ids come from their paths, so the same seed writes the same checkpoint
/// bytes ([`fusiondet_models::checkpoint::deterministic_param_ids`]), which also draws
/// every parameter there and then (none is left to initialise lazily on the device).
pub fn seeded<M: Module>(
    seed: u64,
    device: &Device,
    init: impl FnOnce(&Device) -> Result<M>,
) -> Result<M> {
    static INIT: std::sync::Mutex<()> = std::sync::Mutex::new(());
    let on_cpu = device.clone().without_autodiff() == Device::flex();
    let host = match (on_cpu, device.is_autodiff()) {
        (true, _) => device.clone(),
        (false, true) => Device::flex().autodiff(),
        (false, false) => Device::flex(),
    };
    let model = {
        let _guard = INIT.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
        host.seed(seed);
        init(&host).map(fusiondet_models::checkpoint::deterministic_param_ids)?
    };
    Ok(if on_cpu { model } else { model.fork(device) })
}

/// A run directory opened for training: fresh, or resumed at its last finished epoch.
pub struct OpenedRun {
    pub run: RunDir,
    pub resumed: Option<RunState>,
    /// Held until the training ends.
    pub lock: RunLock,
}

/// Opens `options.run_dir` for `stored` (the configuration as the run keeps it). A
/// resumed run may be given more (or fewer) epochs; `compatible` decides whether the
/// rest of a stored configuration matches.
pub fn open_run(
    options: &TrainOptions,
    stored: &ExperimentConfig,
    compatible: impl Fn(ExperimentConfig) -> bool,
) -> Result<OpenedRun> {
    let run = RunDir::new(&options.run_dir);
    let config_path = run.config();
    let check = |text: &str| {
        ExperimentConfig::from_toml_str(text, &config_path).is_ok_and(|mut old| {
            old.train.epochs = options.config.train.epochs;
            compatible(old)
        })
    };
    let (lock, resumed) = run.open(&stored.to_toml_string(), options.resume, &check)?;
    Ok(OpenedRun { run, resumed, lock })
}

/// The loop: epochs from the resumed state to `config.train.epochs`, each committed to
/// the run directory (checkpoint, optimizer state, `model.bpk`, state, metrics line).
pub fn run_training<T: TrainingTask>(
    task: &T,
    options: &TrainOptions,
    opened: OpenedRun,
) -> Result<TrainSummary> {
    let cfg = &options.config;
    // The lock is held (bound, not dropped) until the loop ends.
    let OpenedRun {
        run,
        resumed,
        lock: _lock,
    } = opened;
    let log = MetricsLog::new(run.metrics());
    if task.samples() < cfg.train.batch_size {
        return Err(PipelineError::Invalid(format!(
            "{} training {}{} are fewer than one batch of {}; use more frames or a smaller \
             train.batch_size",
            task.samples(),
            task.sample_noun(),
            task.sample_note(),
            cfg.train.batch_size
        )));
    }

    let ad = options.device.device().autodiff();
    // Per parameter: clipped inside the optimizer; global: before the step.
    let global_clip = cfg
        .train
        .grad_clip_norm
        .filter(|_| cfg.train.grad_clip_scope == GradClipScope::Global);
    let clipping = cfg
        .train
        .grad_clip_norm
        .filter(|_| global_clip.is_none())
        .map(|n| n as f32);
    let mut optim = TrainingOptimizer::new(
        cfg.train.optimizer == OptimizerKind::AdamW,
        cfg.train.weight_decay as f32,
        clipping,
    )
    .into_module_optimizer();
    let (mut model, start_epoch) = match &resumed {
        Some(state) => {
            let model = task.load_model(&run.root.join(&state.model), &ad)?;
            let record = OptimizerRecord::load(run.root.join(&state.optimizer)).map_err(|e| {
                PipelineError::RunDir {
                    path: run.root.join(&state.optimizer),
                    message: format!("cannot read the optimizer state: {e}"),
                }
            })?;
            optim = optim.load_record(record);
            log.truncate_to(state.epochs_done)?;
            (model, state.epochs_done)
        }
        None => (task.new_model(&ad)?, 0),
    };

    let mut final_loss = None;
    for epoch in start_epoch..cfg.train.epochs {
        let started = Instant::now();
        let batches = task.epoch_batches(epoch);
        let steps_per_epoch = batches.len();
        let mut lr = cfg.train.lr_at(epoch, 0, steps_per_epoch);
        let progress = bar(batches.len(), options.progress);
        progress.set_prefix(format!("epoch {}/{}", epoch + 1, cfg.train.epochs));
        let mut sums: Vec<(&'static str, f64)> = Vec::new();
        let mut steps = 0usize;
        let mut loss_curve = LossCurve::default();
        let mut time = StepTime::default();
        // The data thread prepares batch k+1 while the network trains on batch k.
        let mut slot = Some(model);
        let outcome: Result<()> = std::thread::scope(|scope| {
            let (tx, rx) = std::sync::mpsc::sync_channel::<Result<T::Batch>>(2);
            // The data thread's seconds spent making batches, not waiting to hand them on.
            let preparing = scope.spawn(move || {
                let mut busy = 0.0;
                let mut batches = batches;
                loop {
                    let started = Instant::now();
                    let Some(b) = batches.next() else { break };
                    busy += started.elapsed().as_secs_f64();
                    if tx.send(b).is_err() {
                        break;
                    }
                }
                busy
            });
            // The steps run on the compute pool (see `compute_pool`).
            let rx = rx;
            crate::compute_pool::install(|| {
                let rx = rx;
                loop {
                    let waited = Instant::now();
                    let Ok(prepared) = rx.recv() else { break };
                    time.data_wait += waited.elapsed().as_secs_f64();
                    if stop_requested() {
                        return Err(PipelineError::Interrupted { epochs_done: epoch });
                    }
                    let batch = prepared?;
                    let net = slot.take().expect("the model is put back after every step");
                    lr = cfg.train.lr_at(epoch, steps, steps_per_epoch);
                    let forward = Instant::now();
                    let loss = task.loss(&net, batch, &ad)?;
                    time.forward_loss += forward.elapsed().as_secs_f64();
                    time.forward_parts.absorb(&loss.parts);
                    let update = Instant::now();
                    let mut grads = GradientsParams::from_grads(loss.total.backward(), &net);
                    if let Some(max_norm) = global_clip {
                        grads = crate::grad_clip::clip_global_norm(&net, grads, max_norm).0;
                    }
                    let updated = optim.step(lr, net, grads);
                    let components = loss.components.read()?;
                    time.backward_update += update.elapsed().as_secs_f64();
                    if let Some((name, value)) = components.iter().find(|(_, v)| !v.is_finite()) {
                        // The updated weights are dropped unsaved: the run keeps its last
                        // committed epoch.
                        return Err(PipelineError::Invalid(format!(
                            "training diverged: loss `{name}` is {value} at epoch {}, step {}; \
                             nothing of this epoch is saved (the run keeps epoch {epoch}); lower \
                             the learning rate or check the configuration",
                            epoch + 1,
                            steps + 1
                        )));
                    }
                    slot = Some(updated);
                    if let Some(&(_, total)) = components.first() {
                        loss_curve.push(total as f64);
                    }
                    for (k, (name, value)) in components.into_iter().enumerate() {
                        if sums.len() <= k {
                            sums.push((name, 0.0));
                        }
                        sums[k].1 += value as f64;
                    }
                    steps += 1;
                    progress.set_message(format!("loss {:.3}", sums[0].1 / steps as f64));
                    progress.inc(1);
                }
                Ok(())
            })?;
            // Every batch was taken, so the data thread has finished.
            time.data_prepare = preparing
                .join()
                .map_err(|_| PipelineError::Invalid("the data thread panicked".into()))?;
            Ok(())
        });
        progress.finish_and_clear();
        outcome?;
        model = slot.expect("the model is put back after every step");

        let done = epoch + 1;
        let mut state = RunState {
            epochs_done: done,
            model: run.epoch_model(done),
            optimizer: run.epoch_optimizer(done),
            optimizer_checksum: None,
        };
        task.save_model(&model, &run.root.join(&state.model))?;
        optim
            .to_record()
            .save(run.root.join(&state.optimizer))
            .map_err(|e| PipelineError::RunDir {
                path: run.root.join(&state.optimizer),
                message: format!("cannot write the optimizer state: {e}"),
            })?;
        state.optimizer_checksum = Some(crate::run_dir::file_checksum(
            &run.root.join(&state.optimizer),
        )?);
        task.save_inference_model(&model, &run.model())?;

        // The metrics line goes first and the state commit last: a kill between the two
        // leaves a line beyond the committed epochs, which resume truncates, so an epoch's
        // state and its record are committed together.
        let mut record = json!({
            "epoch": epoch,
            "lr": lr,
            "batches": steps,
            task.sample_noun(): steps * cfg.train.batch_size,
            "seconds": started.elapsed().as_secs_f64(),
            "step_seconds": time.to_json(),
            // Before any update of this epoch: what a CPU and a GPU run of the same seed must
            // agree on within float tolerance in their first epoch (scripts/gpu-check.sh).
            "first_step_loss": loss_curve.0.first(),
            // The epoch's first steps one by one, each before its own update: the curve a
            // GPU run's must follow within float tolerance of the CPU's.
            "loss_curve": loss_curve.0,
        });
        for (name, sum) in &sums {
            record[format!("loss_{name}")] = json!(sum / steps.max(1) as f64);
        }
        final_loss = sums.first().map(|(_, s)| s / steps.max(1) as f64);
        log.append(&record)?;
        run.commit(&state)?;
        let line = format!(
            "epoch {done}/{}: loss {:.4}, lr {lr:.1e}, {:.1} s",
            cfg.train.epochs,
            final_loss.unwrap_or(f64::NAN),
            started.elapsed().as_secs_f64()
        );
        use std::io::{IsTerminal, Write};
        if options.progress {
            eprintln!("{line}");
        }
        // Stdout into a file or a pipe gets every epoch as it ends, bar or not.
        if !options.progress || !std::io::stdout().is_terminal() {
            // A reader that left is no reason to stop training.
            let mut out = std::io::stdout().lock();
            let _ = writeln!(out, "{line}").and_then(|()| out.flush());
        }
    }
    Ok(TrainSummary {
        frames: task.frames(),
        samples: task.samples(),
        sample_noun: task.sample_noun(),
        epochs_run: cfg.train.epochs.saturating_sub(start_epoch),
        epochs_done: cfg.train.epochs.max(start_epoch),
        final_loss,
        model: run.model(),
    })
}

/// The total losses of an epoch's first [`LossCurve::STEPS`] steps, in order (`loss_curve`
/// in `metrics.jsonl`).
#[derive(Debug, Default)]
struct LossCurve(Vec<f64>);

impl LossCurve {
    /// Enough to follow a GPU run's first steps against the CPU's, few enough to keep an
    /// epoch's line short however long the epoch.
    const STEPS: usize = 32;

    fn push(&mut self, total: f64) {
        if self.0.len() < Self::STEPS {
            self.0.push(total);
        }
    }
}

/// Where an epoch's seconds went, summed over its steps: waiting for the data thread's next
/// batch (and, beside the steps, the data thread's own time making them), the forward pass
/// with the loss (the host work a task does inside it, such as targets and the RoI query,
/// included; on a GPU the voxel family's forward pass waits there only for its proposals'
/// read-back, the frustum family's for the loss it reads back), and backward with the
/// optimizer update and the read-back of the loss values (on a GPU the wait for the whole
/// step's queue). Written into `metrics.jsonl` as `step_seconds`, so that a slow step can be
/// told data-bound from compute-bound on any device.
/// Where the family splits its forward pass ([`StepLoss::parts`]), `forward_parts` says how
/// `forward_loss` divides among those parts.
#[derive(Debug, Default, Clone)]
struct StepTime {
    data_wait: f64,
    /// The data thread's own seconds making the epoch's batches: near the epoch's seconds,
    /// the steps are data-bound whatever the device.
    data_prepare: f64,
    forward_loss: f64,
    forward_parts: ForwardParts,
    backward_update: f64,
}

impl StepTime {
    fn to_json(&self) -> serde_json::Value {
        let mut record = json!({
            "data_wait": self.data_wait,
            "data_prepare": self.data_prepare,
            "forward_loss": self.forward_loss,
            "backward_update": self.backward_update,
        });
        if !self.forward_parts.parts().is_empty() {
            let parts: serde_json::Map<String, serde_json::Value> = self
                .forward_parts
                .parts()
                .iter()
                .map(|&(name, seconds)| (name.to_string(), json!(seconds)))
                .collect();
            record["forward_parts"] = serde_json::Value::Object(parts);
        }
        record
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::nn::{Linear, LinearConfig};

    #[test]
    fn the_loss_curve_keeps_the_first_steps_in_order() {
        let mut curve = LossCurve::default();
        for step in 0..LossCurve::STEPS + 5 {
            curve.push(step as f64);
        }
        let expected: Vec<f64> = (0..LossCurve::STEPS).map(|s| s as f64).collect();
        assert_eq!(curve.0, expected);
    }

    #[test]
    fn forward_parts_add_up_by_name_in_the_order_they_first_ran() {
        let mut step = ForwardParts::default();
        assert_eq!(step.time("query", || 7), 7);
        step.add("head", 0.5);
        step.add("query", 1.0);
        let mut epoch = StepTime::default();
        assert!(epoch.to_json().get("forward_parts").is_none());
        epoch.forward_parts.absorb(&step);
        epoch.forward_parts.absorb(&step);
        let names: Vec<&str> = epoch.forward_parts.parts().iter().map(|p| p.0).collect();
        assert_eq!(names, ["query", "head"]);
        let json = epoch.to_json();
        assert_eq!(json["forward_parts"]["head"], 1.0);
        assert!(json["forward_parts"]["query"].as_f64().unwrap() >= 2.0);
    }

    /// A one-weight "network" whose batches scale its loss: a NaN batch makes a NaN loss.
    struct ScaledLoss {
        /// Each epoch's batches (the scales of its steps).
        epochs: Vec<Vec<f32>>,
        /// The name of the thread each step ran on.
        step_threads: std::sync::Mutex<Vec<String>>,
    }

    impl ScaledLoss {
        fn new(epochs: Vec<Vec<f32>>) -> Self {
            Self {
                epochs,
                step_threads: Default::default(),
            }
        }
    }

    impl TrainingTask for ScaledLoss {
        type Model = Linear;
        type Batch = f32;

        fn frames(&self) -> usize {
            1
        }
        fn samples(&self) -> usize {
            self.epochs[0].len()
        }
        fn sample_noun(&self) -> &'static str {
            "frames"
        }
        fn new_model(&self, device: &Device) -> Result<Linear> {
            Ok(LinearConfig::new(1, 1).init(device))
        }
        fn load_model(&self, _path: &Path, device: &Device) -> Result<Linear> {
            self.new_model(device)
        }
        fn save_model(&self, _model: &Linear, path: &Path) -> Result<()> {
            std::fs::write(path, b"weights").map_err(|e| PipelineError::Invalid(e.to_string()))
        }
        fn epoch_batches(
            &self,
            epoch: usize,
        ) -> Box<dyn ExactSizeIterator<Item = Result<f32>> + Send + '_> {
            Box::new(self.epochs[epoch].clone().into_iter().map(Ok))
        }
        fn loss(&self, model: &Linear, scale: f32, device: &Device) -> Result<StepLoss> {
            let name = std::thread::current().name().unwrap_or("").to_string();
            self.step_threads.lock().unwrap().push(name);
            let y = model.forward(Tensor::<2>::ones([1, 1], device));
            Ok(StepLoss::from_terms(vec![(
                "fit",
                y.sum().mul_scalar(scale),
            )]))
        }
    }

    /// Options for `epochs` epochs of batch 1, the run directory under `dir`.
    fn batch_of_one(dir: &Path, epochs: usize) -> (TrainOptions, ExperimentConfig) {
        let mut config = ExperimentConfig::default();
        config.train.epochs = epochs;
        config.train.batch_size = 1;
        let options = TrainOptions {
            config: config.clone(),
            data_dir: dir.join("data"),
            run_dir: dir.join("run"),
            resume: false,
            progress: false,
            device: Default::default(),
        };
        (options, config)
    }

    #[test]
    fn a_diverged_loss_stops_the_run_at_its_last_committed_epoch() {
        let dir = tempfile::tempdir().unwrap();
        let (options, config) = batch_of_one(dir.path(), 3);
        let task = ScaledLoss::new(vec![vec![1.0, 1.0], vec![1.0, f32::NAN], vec![1.0, 1.0]]);
        let opened = open_run(&options, &config, |_| true).unwrap();
        let err = run_training(&task, &options, opened)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("diverged: loss `total` is NaN at epoch 2, step 2"),
            "{err}"
        );
        assert!(err.contains("keeps epoch 1"), "{err}");
        let run = RunDir::new(&options.run_dir);
        let state: RunState =
            serde_json::from_str(&std::fs::read_to_string(run.state()).unwrap()).unwrap();
        assert_eq!(state.epochs_done, 1);
        let lines = std::fs::read_to_string(run.metrics()).unwrap();
        assert_eq!(lines.lines().count(), 1, "{lines}");
    }

    /// Steps run on the compute pool's workers (where flex's parallel loops start in the
    /// pool), not on the calling thread.
    #[test]
    fn steps_run_on_the_compute_pool() {
        let dir = tempfile::tempdir().unwrap();
        let (options, config) = batch_of_one(dir.path(), 1);
        let task = ScaledLoss::new(vec![vec![1.0, 2.0, 3.0]]);
        let opened = open_run(&options, &config, |_| true).unwrap();
        run_training(&task, &options, opened).unwrap();
        let threads = task.step_threads.lock().unwrap().clone();
        assert_eq!(threads.len(), 3);
        for name in &threads {
            let on_pool = name.starts_with(crate::compute_pool::THREAD_PREFIX);
            assert!(on_pool, "a step ran on {name:?}");
        }
    }
}
