//! The stream domains of the frustum data sets, so that e.g. the jitter of object 3
//! and the augmentation of sample 3 never share a stream. The generator itself is the
//! project's one [`Sampler`](fusiondet_dataset::rng::Sampler).

pub use fusiondet_dataset::rng::Sampler;

pub(crate) mod domain {
    pub const JITTER: u64 = 1;
    pub const SAMPLE: u64 = 2;
    pub const ORDER: u64 = 3;
    pub const FRAME_SAMPLE: u64 = 4;
}
