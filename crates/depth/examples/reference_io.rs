//! Side-by-side runs against another implementation of IP-Basic (its authors' Python
//! with OpenCV, `scripts/ip_basic_reference.py`): the exact sparse inputs our CLI
//! completes, our completions as raw floats, and our errors of anyone's completions.
//!
//! ```text
//! cargo run --release -p fusiondet-depth --example reference_io -- inputs DATA_DIR OUT_DIR [HOLDOUT SEED]
//! cargo run --release -p fusiondet-depth --example reference_io -- complete IN_DIR OUT_DIR fast|multiscale gaussian|bilateral extrapolate|no
//! cargo run --release -p fusiondet-depth --example reference_io -- measure DATA_DIR PRED_DIR (truth TRUTH_DIR | holdout HOLDOUT SEED)
//! ```
//!
//! `inputs` writes each frame's projected scan (with `HOLDOUT`: the kept pixels of the
//! CLI's split, seed `SEED ^ frame index`) as `<id>.f32`: little-endian float32,
//! row-major, no header, the sizes in `sizes.txt` (`<id> <width> <height>` a line).
//! `complete` reads such files and writes our completions the same way, printing the
//! median time per frame; `measure` scores `PRED_DIR/<id>.f32` exactly as
//! `fusiondet depth-complete --truth-dir` / `--holdout` score our own completions.
//!
//! The whole comparison, with a checkout of IP-Basic in `$IPB` (numpy and OpenCV
//! installed), for each setting:
//!
//! ```text
//! EX="cargo run -q --release -p fusiondet-depth --example reference_io --"
//! $EX inputs /path/kitti/training /tmp/in 0.1 1
//! $EX complete /tmp/in /tmp/ours fast gaussian extrapolate
//! python3 scripts/ip_basic_reference.py $IPB /tmp/in /tmp/theirs fast gaussian extrapolate /tmp/ours
//! $EX measure /path/kitti/training /tmp/theirs holdout 0.1 1
//! ```

use fusiondet_dataset::SensorFrame;
use fusiondet_depth::{
    Blur, DepthErrors, DepthMap, IpBasic, Method, complete, depth_errors, frame_ids, project_scan,
    read_depth_png, restrict_to_scan_coverage, split_holdout,
};
use fusiondet_kitti::FrameDir;
use std::path::Path;

type Res<T> = Result<T, Box<dyn std::error::Error>>;

fn write_raw(path: &Path, map: &DepthMap) -> Res<()> {
    let bytes: Vec<u8> = map.data.iter().flat_map(|v| v.to_le_bytes()).collect();
    std::fs::write(path, bytes)?;
    Ok(())
}

fn read_raw(path: &Path, width: usize, height: usize) -> Res<DepthMap> {
    let bytes = std::fs::read(path)?;
    if bytes.len() != width * height * 4 {
        return Err(format!("{}: not {width}×{height} float32", path.display()).into());
    }
    let data = bytes
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect();
    Ok(DepthMap {
        width,
        height,
        data,
    })
}

/// Each frame's projected scan, with its index (the CLI's holdout seed mixes it in).
fn frames(data_dir: &str) -> Res<Vec<(usize, String, DepthMap)>> {
    let frames = FrameDir::new(data_dir);
    let ids = frame_ids(&frames, &[])?;
    let mut out = Vec::new();
    for (k, id) in ids.into_iter().enumerate() {
        let frame = SensorFrame::load(&frames, &id, false)?;
        let sparse = project_scan(&frame);
        out.push((k, id, sparse));
    }
    Ok(out)
}

fn line(e: &DepthErrors) -> String {
    format!(
        "{} pixels ({} left empty), MAE {:.1} mm, RMSE {:.1} mm, iMAE {:.2} /km, iRMSE {:.2} /km",
        e.pixels, e.missing, e.mae_mm, e.rmse_mm, e.imae_per_km, e.irmse_per_km
    )
}

fn main() -> Res<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let a: Vec<&str> = args.iter().map(String::as_str).collect();
    match a.as_slice() {
        ["inputs", data, out, rest @ ..] => {
            std::fs::create_dir_all(out)?;
            let holdout = match rest {
                [] => None,
                [f, s] => Some((f.parse::<f64>()?, s.parse::<u64>()?)),
                _ => return Err("inputs DATA_DIR OUT_DIR [HOLDOUT SEED]".into()),
            };
            let mut sizes = String::new();
            for (k, id, sparse) in frames(data)? {
                let input = match holdout {
                    Some((f, seed)) => split_holdout(&sparse, f, seed ^ k as u64).0,
                    None => sparse,
                };
                write_raw(&Path::new(out).join(format!("{id}.f32")), &input)?;
                sizes += &format!("{id} {} {}\n", input.width, input.height);
            }
            std::fs::write(Path::new(out).join("sizes.txt"), sizes)?;
        }
        ["complete", input_dir, out, method, blur, extrapolate] => {
            std::fs::create_dir_all(out)?;
            let settings = IpBasic {
                method: match *method {
                    "fast" => Method::Fast,
                    "multiscale" => Method::Multiscale,
                    m => return Err(format!("method {m}?").into()),
                },
                blur: match *blur {
                    "gaussian" => Blur::Gaussian,
                    "bilateral" => Blur::Bilateral,
                    b => return Err(format!("blur {b}?").into()),
                },
                extrapolate: *extrapolate == "extrapolate",
                ..Default::default()
            };
            // The sizes come from `inputs`' listing beside the files.
            let listing = std::fs::read_to_string(Path::new(input_dir).join("sizes.txt"))?;
            let mut times = Vec::new();
            for row in listing.lines() {
                let f: Vec<&str> = row.split_whitespace().collect();
                let [id, w, h] = f.as_slice() else {
                    return Err(format!("sizes.txt: {row:?}").into());
                };
                let path = Path::new(input_dir).join(format!("{id}.f32"));
                let sparse = read_raw(&path, w.parse()?, h.parse()?)?;
                // Timed as the reference script times IP-Basic's code: median of 5 runs.
                let mut runs = Vec::new();
                let mut dense = None;
                for _ in 0..5 {
                    let start = std::time::Instant::now();
                    dense = Some(complete(&sparse, &settings));
                    runs.push(start.elapsed().as_secs_f64());
                }
                runs.sort_by(f64::total_cmp);
                times.push(runs[2]);
                let dense = dense.expect("five runs");
                write_raw(&Path::new(out).join(format!("{id}.f32")), &dense)?;
            }
            times.sort_by(f64::total_cmp);
            println!(
                "{} frames, completion time median {:.2} ms (one thread)",
                times.len(),
                1000.0 * times[times.len() / 2]
            );
        }
        ["measure", data, pred, rest @ ..] => {
            let mut parts = Vec::new();
            for (k, id, sparse) in frames(data)? {
                let p = read_raw(
                    &Path::new(pred).join(format!("{id}.f32")),
                    sparse.width,
                    sparse.height,
                )?;
                let e = match rest {
                    ["truth", dir] => {
                        let mut truth = read_depth_png(&Path::new(dir).join(format!("{id}.png")))?;
                        restrict_to_scan_coverage(&mut truth, &sparse, 80.0);
                        depth_errors(&p, &truth)?
                    }
                    ["holdout", f, s] => {
                        let held =
                            split_holdout(&sparse, f.parse()?, s.parse::<u64>()? ^ k as u64).1;
                        depth_errors(&p, &held)?
                    }
                    _ => return Err("measure DATA PRED (truth DIR | holdout F SEED)".into()),
                };
                println!("{id}: {}", line(&e));
                parts.push(e);
            }
            println!(
                "all {} frames: {}",
                parts.len(),
                line(&DepthErrors::pool(&parts))
            );
        }
        _ => return Err("inputs | complete | measure (see the file's documentation)".into()),
    }
    Ok(())
}
