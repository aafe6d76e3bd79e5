//! Workflows that chain the library's steps (what the binary used to do itself): the
//! demo, and the data and models built into the binary for it.

pub mod bundled;
pub mod demo;
