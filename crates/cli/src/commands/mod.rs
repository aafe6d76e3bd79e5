//! One module per subcommand: argument parsing and wiring only; the work lives in the library crates.

pub mod ablation;
pub mod bench;
pub mod compare;
pub mod data_root;
pub mod demo;
pub mod depth_complete;
pub mod detect;
pub mod eval;
pub mod gt_database;
pub mod info;
pub mod merge;
pub mod omega_study;
pub mod outputs;
pub mod progress;
pub mod pseudo_points;
pub mod shards;
pub mod simulate;
pub mod train;
pub mod view;
pub mod viz;
