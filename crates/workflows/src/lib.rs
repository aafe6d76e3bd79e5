//! Workflows that chain the library's steps (what the binary used to do itself): the
//! demo, the ablation (trainings in child processes, detection, evaluation, tables and
//! plots), and the data and models built into the binary for the demo.

pub mod ablation;
pub mod bundled;
pub mod demo;
