//! One module per subcommand: argument parsing and wiring only; the work lives in the library crates.

pub mod eval;
pub mod simulate;
pub mod viz;
