//! `fusiondet compare`: two result directories of the same frames, box by box — the parity
//! check between backends (`detect --device cpu` against `--device cuda`), builds or machines.
//! Exits non-zero when a box has no partner or a difference exceeds the tolerance.

use anyhow::{Context, bail};
use fusiondet_eval::compare::{Tolerance, compare_dirs};
use fusiondet_workflows::outln;
use std::path::PathBuf;

#[derive(clap::Args)]
#[command(after_help = "\
Example:
  fusiondet detect --checkpoint models/voxel-rcnn-car.bpk --data D --out cpu
  fusiondet detect --checkpoint models/voxel-rcnn-car.bpk --data D --out gpu --device cuda
  fusiondet compare cpu gpu          # same boxes within 1 cm, 0.01 rad and 1e-3 in score?")]
pub struct CompareArgs {
    /// First result directory (KITTI result files, `NNNNNN.txt`).
    a: PathBuf,
    /// Second result directory.
    b: PathBuf,
    /// Largest centre offset and size change allowed, metres.
    #[arg(long, default_value_t = Tolerance::default().metres)]
    max_metres: f64,
    /// Largest heading change allowed, radians.
    #[arg(long, default_value_t = Tolerance::default().radians)]
    max_radians: f64,
    /// Largest score change allowed.
    #[arg(long, default_value_t = Tolerance::default().score)]
    max_score: f64,
}

pub fn run(args: CompareArgs) -> anyhow::Result<()> {
    let tol = Tolerance {
        metres: args.max_metres,
        radians: args.max_radians,
        score: args.max_score,
    };
    for (name, v) in [
        ("--max-metres", tol.metres),
        ("--max-radians", tol.radians),
        ("--max-score", tol.score),
    ] {
        if !(v.is_finite() && v >= 0.0) {
            bail!("{name} {v}: a tolerance is a finite number ≥ 0");
        }
    }
    for dir in [&args.a, &args.b] {
        if !dir.is_dir() {
            bail!(
                "{}: no such directory (a result directory written by `fusiondet detect`)",
                dir.display()
            );
        }
    }
    let comparison = compare_dirs(&args.a, &args.b)
        .with_context(|| format!("comparing {} with {}", args.a.display(), args.b.display()))?;
    if comparison.frames == 0 {
        bail!(
            "neither {} nor {} holds a result file (NNNNNN.txt)",
            args.a.display(),
            args.b.display()
        );
    }
    outln!("{}", comparison.summary(&tol).trim_end());
    if !comparison.within(&tol) {
        bail!(
            "the two result directories differ beyond the tolerance ({} m, {} rad, {} in score)",
            tol.metres,
            tol.radians,
            tol.score
        );
    }
    outln!(
        "same boxes within {} m, {} rad and {} in score",
        tol.metres,
        tol.radians,
        tol.score
    );
    Ok(())
}
