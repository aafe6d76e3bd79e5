//! Seeding of simulated worlds. Every random choice flows from `(seed, frame index)`:
//!
//! * sequential choices (scene layout, calibration, the 2D detector) draw from the
//!   project's [`Sampler`] keyed by `(seed, index, stream)`, one stream per concern so
//!   that changing how one concern draws does not reshuffle the others;
//! * per-ray choices (range noise, dropouts) use the stateless counter hashes
//!   [`hash_unit`] / [`hash_normal`] of `(frame key, ray, salt)`, so rays can be cast on
//!   any number of threads and still give byte-identical output.

pub use fusiondet_dataset::rng::{Sampler, derive, hash_normal, hash_unit, mix64};

/// The independent random streams of one frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u64)]
pub enum Stream {
    Layout = 1,
    Calib = 2,
    Lidar = 3,
    Detector = 4,
    Split = 5,
}

/// The key of one frame's stream: a different world for a different seed or index.
pub fn frame_key(seed: u64, index: u64, stream: Stream) -> u64 {
    derive(&[seed, index, stream as u64])
}

/// The sampler of one frame's stream.
pub fn frame_sampler(seed: u64, index: u64, stream: Stream) -> Sampler {
    Sampler::new(frame_key(seed, index, stream))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_streams_are_distinct() {
        let first = |seed, index, stream| frame_sampler(seed, index, stream).next_u64();
        let a = first(7, 3, Stream::Layout);
        assert_eq!(a, first(7, 3, Stream::Layout));
        assert_ne!(a, first(7, 4, Stream::Layout));
        assert_ne!(a, first(8, 3, Stream::Layout));
        assert_ne!(a, first(7, 3, Stream::Lidar));
    }
}
