//! `fusiondet gt-database`: the ground-truth database Voxel R-CNN's augmentation pastes
//! objects from, built once from a split's labelled frames and kept beside the data; with
//! `--pseudo`, DASANet's, whose objects carry their pseudo points too.

use fusiondet_pipeline::ExperimentConfig;
use fusiondet_pipeline::dasanet::pseudo::PseudoCloudMaker;
use fusiondet_pipeline::dasanet::{
    PseudoCloudConfig, build_pseudo_gt_database, data_pseudo_gt_database_dir,
};
use fusiondet_pipeline::voxel_rcnn::{build_gt_database, data_gt_database_dir};
use fusiondet_workflows::outln;
use std::collections::BTreeMap;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct GtDatabaseArgs {
    /// Dataset root with training/ and ImageSets/.
    #[arg(long)]
    pub data: PathBuf,
    /// The split whose labelled objects go in (training uses the database of its own split).
    #[arg(long, default_value = "train")]
    pub split: String,
    /// Replace an existing database of the split.
    #[arg(long)]
    pub force: bool,
    /// DASANet's database: each object with its pseudo points (the frame's scan completed
    /// and back-projected as the configuration's `[dasanet.pseudo]` says).
    #[arg(long)]
    pub pseudo: bool,
    /// The DASANet configuration whose pseudo-cloud settings and point range to use with
    /// `--pseudo` (default: the published ones).
    #[arg(long, requires = "pseudo")]
    pub config: Option<PathBuf>,
}

pub fn run(args: GtDatabaseArgs) -> anyhow::Result<()> {
    super::data_root::check_root("--data", &args.data)?;
    let out = if args.pseudo {
        data_pseudo_gt_database_dir(&args.data, fusiondet_kitti::split_name(&args.split))
    } else {
        data_gt_database_dir(&args.data, fusiondet_kitti::split_name(&args.split))
    };
    if out.join("index.json").exists() && !args.force {
        anyhow::bail!(
            "{} already holds a ground-truth database; pass --force to rebuild it",
            out.display()
        );
    }
    let frames = fusiondet_dataset::load_split(&args.data, &args.split, 0, true)?;
    let bar = super::progress::bar(
        "gt-database",
        fusiondet_dataset::FrameSource::len(&frames),
        "frames",
    );
    let db = if args.pseudo {
        let (settings, range) = match &args.config {
            Some(path) => {
                let c = ExperimentConfig::from_file(path)?;
                match (&c.voxel_rcnn, &c.dasanet) {
                    (Some(v), Some(d)) => (d.pseudo.clone(), v.voxels.point_range),
                    _ => anyhow::bail!("{}: not a dasanet configuration", path.display()),
                }
            }
            None => (
                PseudoCloudConfig::default(),
                fusiondet_pipeline::voxel_rcnn::VoxelRcnnSection::default()
                    .voxels
                    .point_range,
            ),
        };
        build_pseudo_gt_database(&frames, &PseudoCloudMaker::new(&settings, range), &|| {
            bar.inc(1)
        })?
    } else {
        build_gt_database(&frames, &|| bar.inc(1))?
    };
    bar.finish_and_clear();
    db.save(&out)?;
    let mut per_class: BTreeMap<String, (usize, usize)> = BTreeMap::new();
    for o in db.objects() {
        let e = per_class.entry(o.class.to_string()).or_default();
        e.0 += 1;
        e.1 += o.num_points;
    }
    let classes: Vec<String> = per_class
        .iter()
        .map(|(c, (n, p))| format!("{c} {n} ({p} LiDAR points)"))
        .collect();
    outln!(
        "{} objects from {} frames of `{}` -> {}: {}",
        db.objects().len(),
        fusiondet_dataset::FrameSource::len(&frames),
        args.split,
        out.display(),
        classes.join(", ")
    );
    Ok(())
}
