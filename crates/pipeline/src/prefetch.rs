//! Frames prepared ahead of the network: a second thread runs each frame's host-side work
//! (voxelisation, depth completion, rulebooks) while the network runs on the frame before.
//!
//! Why: run one after the other, a GPU idles through all of a frame's host-side stages (on
//! an H200, Voxel R-CNN's host rulebooks alone were 20.6 of its 38.9 ms a frame, and
//! DASANet's depth completion 41 of 166 ms). The preparation of a frame reads nothing the
//! network writes, so the results are the same bits in either order; the trainer's data
//! thread does the same for batches.

use crate::detection::StageTimes;
use std::sync::mpsc::sync_channel;
use std::time::Instant;

/// How many prepared frames may wait for the network: one to run next, one in reserve for
/// a frame that prepares slower than the one before it.
pub const FRAMES_AHEAD: usize = 2;

/// Runs `prepare(i)` for `i` in `0..count` on a second thread, in order and at most
/// [`FRAMES_AHEAD`] frames ahead, and `consume` on each prepared frame on this thread in
/// the same order. Both add their stages' times to `timing`; the time the two threads ran side by
/// side is recorded as overlap, so `timing.compute()` is the wall time of the pass. Stops
/// at the first error of either side and returns it.
pub fn prepared_in_order<T: Send, E: Send>(
    count: usize,
    timing: &mut StageTimes,
    prepare: impl Fn(usize, &mut StageTimes) -> Result<T, E> + Sync,
    mut consume: impl FnMut(T, &mut StageTimes) -> Result<(), E>,
) -> Result<(), E> {
    let started = Instant::now();
    let mut pass = StageTimes::default();
    let outcome = std::thread::scope(|scope| {
        let (tx, rx) = sync_channel::<(Result<T, E>, StageTimes)>(FRAMES_AHEAD);
        let prepare = &prepare;
        scope.spawn(move || {
            for index in 0..count {
                let mut times = StageTimes::default();
                let prepared = prepare(index, &mut times);
                let failed = prepared.is_err();
                // A closed channel means the consumer stopped (an error): nothing more to do.
                if tx.send((prepared, times)).is_err() || failed {
                    break;
                }
            }
        });
        for _ in 0..count {
            // The sender only goes away early after sending an error, which returns below;
            // a panic on its side reaches the caller when the scope joins it.
            let Ok((prepared, times)) = rx.recv() else {
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
    use std::time::Duration;

    /// The consumer sees every frame once, in order, and the pass's compute time is its
    /// wall time although the two threads' stages add up to more.
    #[test]
    fn frames_arrive_in_order_and_overlap_is_not_counted_twice() {
        let mut timing = StageTimes::default();
        let mut seen = Vec::new();
        let pause = Duration::from_millis(20);
        prepared_in_order::<(usize, usize), String>(
            6,
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
            "compute {:?} counts the overlap",
            timing.compute()
        );
        assert!(timing.compute() >= pause * 6);
    }

    /// An error on either side stops the pass and comes back; frames after it are not consumed.
    #[test]
    fn the_first_error_of_either_side_is_returned() {
        let mut timing = StageTimes::default();
        let mut consumed = 0;
        let out = prepared_in_order(
            10,
            &mut timing,
            |i, _| {
                if i == 3 {
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
        assert_eq!(out, Err("bad frame 3".to_string()));
        assert_eq!(consumed, 3);

        let mut consumed = 0;
        let out = prepared_in_order(
            10,
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

    /// No frames: nothing runs and nothing is timed but an empty pass.
    #[test]
    fn an_empty_pass_runs_nothing() {
        let mut timing = StageTimes::default();
        prepared_in_order::<(), String>(
            0,
            &mut timing,
            |_, _| panic!("no frame to prepare"),
            |_, _| panic!("no frame to consume"),
        )
        .unwrap();
        assert!(timing.stages().is_empty());
    }
}
