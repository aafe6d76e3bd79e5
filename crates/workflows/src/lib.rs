//! Workflows that chain the library's steps (what the binary used to do itself): the
//! demo (street and indoor), the ablation (trainings in child processes, detection, evaluation, tables and
//! plots), the data and models built into the binary for the demo, and the console output
//! that all commands print through.

pub mod ablation;
pub mod bundled;
pub mod console;
pub mod demo;
pub mod indoor_demo;
