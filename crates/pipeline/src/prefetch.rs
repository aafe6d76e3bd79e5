//! Frames prepared ahead of the network: threads beside it run each frame's host-side work
//! (voxelisation, depth completion, rulebooks) and then, for the voxel family, its stage one
//! ([`stage_one_ahead`]), while the network's thread takes the frames before through stage
//! two.
//!
//! Why: run one after the other, a GPU idles through all of a frame's host-side stages (on
//! an H200, Voxel R-CNN's host rulebooks alone were 20.6 of its 38.9 ms a frame, and
//! DASANet's depth completion 41 of 166 ms). With one thread preparing beside a GPU the
//! host is still the bound where a frame prepares slower than the network runs (the
//! published DASANet on the H200: about 150 ms of host work a frame, 163 ms a frame in
//! all), so beside a GPU several threads prepare frames at once ([`preparers_for`]). The
//! preparation of a frame reads nothing the network or another frame's preparation writes
//! (stage one reads the weights only), so the results are the same bits in any order and
//! with any number of threads; the trainer's data thread does the same for batches.

use crate::detection::StageTimes;
use burn::prelude::*;
use std::sync::mpsc::sync_channel;
use std::time::Instant;

/// How many prepared frames may wait for the network, per preparing thread: one to run
/// next, one in reserve for a frame that prepares slower than the one before it.
pub const FRAMES_AHEAD: usize = 2;

/// The environment variable that sets how many threads prepare frames (1 to
/// [`MAX_PREPARERS`]), overriding [`preparers_for`]'s choice: for A/B runs.
pub const PREPARERS_VAR: &str = "FUSIONDET_PREPARE_THREADS";

/// Most preparing threads: each holds its frames' clouds and uploaded inputs.
pub const MAX_PREPARERS: usize = 8;

/// The environment variable that says where a frame's stage one (the network up to its
/// proposals) runs: `on` (the default, [`stage_one_ahead_for`]), on the thread that
/// prepared the frame, `off`, on the network's thread after the frames before it. For A/B
/// runs.
pub const STAGE_ONE_VAR: &str = "FUSIONDET_STAGE_ONE_AHEAD";

/// How many threads prepare frames for a network on `device`: [`preparers_for`] with this
/// machine's cores and [`PREPARERS_VAR`].
pub fn preparers(device: &Device) -> Result<usize, String> {
    #[cfg(any(feature = "wgpu", feature = "cuda"))]
    let on_gpu = fusiondet_nn::cube::cube_runtime(device).is_some();
    // A build without a GPU backend has only the CPU.
    #[cfg(not(any(feature = "wgpu", feature = "cuda")))]
    let on_gpu = {
        let _ = device;
        false
    };
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    preparers_for(on_gpu, cores, std::env::var(PREPARERS_VAR).ok().as_deref())
}

/// One thread beside a network on the CPU, which already runs on every core (a second
/// preparer would take cores from it); beside a GPU, a thread per four cores, one to four
/// (a 16-core GPU machine: four), since there the network leaves the cores idle. `setting`
/// (the value of [`PREPARERS_VAR`]) overrides both.
pub fn preparers_for(on_gpu: bool, cores: usize, setting: Option<&str>) -> Result<usize, String> {
    if let Some(text) = setting {
        return match text.trim().parse::<usize>() {
            Ok(n) if (1..=MAX_PREPARERS).contains(&n) => Ok(n),
            _ => Err(format!(
                "{PREPARERS_VAR}={text:?}: give a whole number of threads from 1 to \
                 {MAX_PREPARERS}, or unset it to let the device decide"
            )),
        };
    }
    Ok(if on_gpu { (cores / 4).clamp(1, 4) } else { 1 })
}

/// Whether the voxel family's detectors run each frame's stage one on the thread that
/// prepared it: [`stage_one_ahead_for`] with [`STAGE_ONE_VAR`].
pub fn stage_one_ahead() -> Result<bool, String> {
    stage_one_ahead_for(std::env::var(STAGE_ONE_VAR).ok().as_deref())
}

/// By default stage one runs on the preparing threads. Beside a GPU each thread's work goes
/// to a device stream of its own, so frame k + 1's stage one runs on the device while the
/// network's thread takes frame k through stage two, and the host's proposal NMS, which
/// waits for stage one's outputs, no longer leaves the device idle. On the CPU stage two's
/// host work (the RoI query, STCA's crops, the NMS) overlaps the next frame's stage one in
/// the same way. `setting` (the value of [`STAGE_ONE_VAR`]: `on` or `off`) overrides it.
pub fn stage_one_ahead_for(setting: Option<&str>) -> Result<bool, String> {
    match setting.map(str::trim) {
        None | Some("on") => Ok(true),
        Some("off") => Ok(false),
        Some(text) => Err(format!(
            "{STAGE_ONE_VAR}={text:?}: give `on` (stage one on the threads that prepare \
             frames, the default) or `off` (on the network's thread), or unset it"
        )),
    }
}

/// Runs `prepare(i)` for `i` in `0..count` on `preparers` threads (thread k prepares frames
/// k, k + preparers, …, each at most [`FRAMES_AHEAD`] ahead), and `consume` on each
/// prepared frame on this thread in frame order. Both add their stages' times to `timing`;
/// the time the threads ran side by side is recorded as overlap, so `timing.compute()` is
/// the wall time of the pass. Stops at the first error, in frame order, and returns it.
pub fn prepared_in_order<T: Send, E: Send>(
    count: usize,
    preparers: usize,
    timing: &mut StageTimes,
    prepare: impl Fn(usize, &mut StageTimes) -> Result<T, E> + Sync,
    mut consume: impl FnMut(T, &mut StageTimes) -> Result<(), E>,
) -> Result<(), E> {
    let preparers = preparers.clamp(1, count.max(1));
    let started = Instant::now();
    let mut pass = StageTimes::default();
    let outcome = std::thread::scope(|scope| {
        let prepare = &prepare;
        let queues: Vec<_> = (0..preparers)
            .map(|first| {
                let (tx, rx) = sync_channel::<(Result<T, E>, StageTimes)>(FRAMES_AHEAD);
                scope.spawn(move || {
                    for index in (first..count).step_by(preparers) {
                        let mut times = StageTimes::default();
                        let prepared = prepare(index, &mut times);
                        let failed = prepared.is_err();
                        // A closed channel means the consumer stopped (an error): nothing
                        // more to do.
                        if tx.send((prepared, times)).is_err() || failed {
                            break;
                        }
                    }
                });
                rx
            })
            .collect();
        for index in 0..count {
            // A sender only goes away early after sending an error, which returns below;
            // a panic on its side reaches the caller when the scope joins it. Returning
            // drops the queues, which stops the other threads at their next send.
            let Ok((prepared, times)) = queues[index % preparers].recv() else {
                break;
            };
            pass.absorb(&times);
            consume(prepared?, &mut pass)?;
        }
        Ok(())
    });
    pass.set_wall(started.elapsed());
    timing.absorb(&pass);
    outcome
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::{Condvar, Mutex};
    use std::time::Duration;

    /// The consumer sees every frame once, in order, whatever the number of preparing
    /// threads, and the pass's compute time is its wall time although the threads' stages
    /// add up to more.
    #[test]
    fn frames_arrive_in_order_and_overlap_is_not_counted_twice() {
        for preparers in [1, 2, 3] {
            let mut timing = StageTimes::default();
            let mut seen = Vec::new();
            let pause = Duration::from_millis(20);
            prepared_in_order::<(usize, usize), String>(
                6,
                preparers,
                &mut timing,
                |i, t| {
                    std::thread::sleep(pause);
                    t.add("prepare", pause);
                    Ok((i, i * 10))
                },
                |v, t| {
                    std::thread::sleep(pause);
                    t.add("network", pause);
                    seen.push(v);
                    Ok(())
                },
            )
            .unwrap();
            assert_eq!(seen, (0..6).map(|i| (i, i * 10)).collect::<Vec<_>>());
            assert_eq!(timing.get("prepare"), pause * 6);
            assert_eq!(timing.get("network"), pause * 6);
            // Side by side the 12 pauses take about 7 pause lengths, one after the other 12.
            assert!(
                timing.compute() < pause * 11,
                "{preparers} preparers: compute {:?} counts the overlap",
                timing.compute()
            );
            assert!(timing.compute() >= pause * 6);
        }
    }

    /// With three preparing threads three frames are prepared at once: each of the first
    /// three waits until all three have started (a single thread would wait out the
    /// time limit on the first).
    #[test]
    fn several_preparers_prepare_frames_at_once() {
        let started = Mutex::new(0usize);
        let all_started = Condvar::new();
        let met = Mutex::new(Vec::new());
        let mut timing = StageTimes::default();
        prepared_in_order::<usize, String>(
            3,
            3,
            &mut timing,
            |i, _| {
                let mut count = started.lock().unwrap();
                *count += 1;
                all_started.notify_all();
                let (count, waited) = all_started
                    .wait_timeout_while(count, Duration::from_secs(30), |c| *c < 3)
                    .unwrap();
                met.lock().unwrap().push((i, *count, waited.timed_out()));
                Ok(i)
            },
            |_, _| Ok(()),
        )
        .unwrap();
        let mut met = met.into_inner().unwrap();
        met.sort();
        assert_eq!(met, vec![(0, 3, false), (1, 3, false), (2, 3, false)]);
    }

    /// An error on either side stops the pass and comes back; frames after it are not
    /// consumed, and with several preparers the first error in frame order is the one.
    #[test]
    fn the_first_error_of_either_side_is_returned() {
        for preparers in [1, 3] {
            let mut timing = StageTimes::default();
            let mut consumed = 0;
            let out = prepared_in_order(
                10,
                preparers,
                &mut timing,
                |i, _| {
                    if i == 3 || i == 5 {
                        Err(format!("bad frame {i}"))
                    } else {
                        Ok(i)
                    }
                },
                |_, _| {
                    consumed += 1;
                    Ok(())
                },
            );
            assert_eq!(out, Err("bad frame 3".to_string()), "{preparers} preparers");
            assert_eq!(consumed, 3);

            let mut consumed = 0;
            let out = prepared_in_order(
                10,
                preparers,
                &mut timing,
                |i, _| Ok::<usize, String>(i),
                |i, _| {
                    consumed += 1;
                    if i == 1 {
                        Err("network failed".to_string())
                    } else {
                        Ok(())
                    }
                },
            );
            assert_eq!(out, Err("network failed".to_string()));
            assert_eq!(consumed, 2);
        }
    }

    /// One preparer beside the CPU, a quarter of the cores (1 to 4) beside a GPU; the
    /// variable overrides both and a bad value is refused with what to do.
    #[test]
    fn preparers_follow_the_device_and_the_variable() {
        assert_eq!(preparers_for(false, 16, None), Ok(1));
        assert_eq!(preparers_for(true, 16, None), Ok(4));
        assert_eq!(preparers_for(true, 64, None), Ok(4));
        assert_eq!(preparers_for(true, 8, None), Ok(2));
        assert_eq!(preparers_for(true, 2, None), Ok(1));
        assert_eq!(preparers_for(false, 2, Some("3")), Ok(3));
        assert_eq!(preparers_for(true, 16, Some(" 1 ")), Ok(1));
        for bad in ["0", "9", "two", "-1", ""] {
            let err = preparers_for(true, 16, Some(bad)).unwrap_err();
            assert!(
                err.contains(PREPARERS_VAR) && err.contains("1 to 8"),
                "{bad:?}: {err}"
            );
        }
    }

    #[test]
    fn stage_one_follows_the_variable() {
        assert_eq!(stage_one_ahead_for(None), Ok(true));
        assert_eq!(stage_one_ahead_for(Some("on")), Ok(true));
        assert_eq!(stage_one_ahead_for(Some(" off ")), Ok(false));
        for bad in ["1", "yes", "", "ON"] {
            let err = stage_one_ahead_for(Some(bad)).unwrap_err();
            assert!(
                err.contains(STAGE_ONE_VAR) && err.contains("`on`"),
                "{bad:?}: {err}"
            );
        }
    }

    /// No frames: nothing runs and nothing is timed but an empty pass.
    #[test]
    fn an_empty_pass_runs_nothing() {
        let mut timing = StageTimes::default();
        prepared_in_order::<(), String>(
            0,
            3,
            &mut timing,
            |_, _| panic!("no frame to prepare"),
            |_, _| panic!("no frame to consume"),
        )
        .unwrap();
        assert!(timing.stages().is_empty());
    }
}
