//! `fusiondet pseudo-points` end to end on a bundled KITTI frame.

mod common;

use common::{all_output, assert_fails_with, repo_root, run, s};

#[test]
fn pseudo_points_carry_colour_and_pixel_and_project_back_onto_it() {
    let dir = tempfile::tempdir().unwrap();
    let training = repo_root().join("data/kitti-sample/training");
    let (full, thin) = (dir.path().join("full"), dir.path().join("thin"));
    for (out, extra) in [(&full, None), (&thin, Some("--thin"))] {
        let mut args = vec![
            "--data-dir",
            s(&training),
            "--ids",
            "000001",
            "--out-dir",
            s(out),
        ];
        args.extend(extra);
        let o = run("pseudo-points", &args);
        assert!(o.status.success(), "{}", all_output(&o));
    }
    let points = fusiondet_depth::read_pseudo_points(&full.join("000001.bin")).unwrap();
    let thinned = fusiondet_depth::read_pseudo_points(&thin.join("000001.bin")).unwrap();
    assert!(points.len() > 200_000, "{}", points.len());
    assert!(thinned.len() < points.len() && thinned.len() > points.len() / 4);
    let camera = fusiondet_kitti::read_calib(&training.join("calib/000001.txt"))
        .unwrap()
        .camera_model()
        .unwrap();
    let image = fusiondet_kitti::image::read_image(&training.join("image_2/000001.png")).unwrap();
    for p in points.iter().step_by(997) {
        let (u, v, _) = camera.velo_to_image(p.xyz.map(f64::from));
        // Back through the camera, each point lands in the pixel it came from.
        assert!(
            (u - p.uv[0] as f64 - 0.5).abs() < 0.01 && (v - p.uv[1] as f64 - 0.5).abs() < 0.01,
            "{p:?} -> ({u}, {v})"
        );
        let c = image.get_pixel(p.uv[0] as u32, p.uv[1] as u32).0;
        assert_eq!(p.rgb, c.map(f32::from));
    }

    // The picture: pseudo points on the bird's-eye view, the depth above the image.
    let depth = dir.path().join("depth");
    let o = run(
        "depth-complete",
        &[
            "--data-dir",
            s(&training),
            "--ids",
            "000001",
            "--out-dir",
            s(&depth),
        ],
    );
    assert!(o.status.success(), "{}", all_output(&o));
    let picture = dir.path().join("frame.png");
    let o = run(
        "viz",
        &[
            "--data-dir",
            s(&training),
            "--id",
            "1",
            "--pseudo-dir",
            s(&full),
            "--depth-dir",
            s(&depth),
            "--out",
            s(&picture),
        ],
    );
    assert!(o.status.success(), "{}", all_output(&o));
    let drawn = fusiondet_kitti::image::read_image(&picture).unwrap();
    assert!(drawn.height() > 2 * 375, "{}", drawn.height());
}

#[test]
fn a_depth_map_of_another_size_and_an_input_output_directory_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let training = repo_root().join("data/kitti-sample/training");
    let depth = dir.path().join("depth");
    std::fs::create_dir(&depth).unwrap();
    fusiondet_depth::write_depth_png(
        &depth.join("000001.png"),
        &fusiondet_depth::DepthMap::empty(100, 50),
    )
    .unwrap();
    let o = run(
        "pseudo-points",
        &[
            "--data-dir",
            s(&training),
            "--depth-dir",
            s(&depth),
            "--ids",
            "000001",
            "--out-dir",
            s(&dir.path().join("out")),
        ],
    );
    assert!(!o.status.success());
    let t = all_output(&o);
    assert!(t.contains("000001.png") && t.contains("100×50"), "{t}");
    assert_fails_with(
        "pseudo-points",
        &[
            "--data-dir",
            s(&training),
            "--out-dir",
            s(&depth),
            "--depth-dir",
            s(&depth),
        ],
        "is an input directory",
    );
}
