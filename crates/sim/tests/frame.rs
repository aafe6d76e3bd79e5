//! Whole-frame properties: determinism (also across thread counts), KITTI validity,
//! and agreement between the point cloud and the image.

use fusiondet_kitti::ObjectClass;
use fusiondet_sim::camera::SKY;
use fusiondet_sim::primitive::Surface;
use fusiondet_sim::{SimConfig, SimFrame, simulate_frame};
use std::sync::OnceLock;

fn frame() -> &'static SimFrame {
    static F: OnceLock<SimFrame> = OnceLock::new();
    F.get_or_init(|| simulate_frame(11, 2, &SimConfig::default()))
}

#[test]
fn same_seed_same_frame_on_any_thread_count() {
    let a = frame();
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let b = one.install(|| simulate_frame(11, 2, &SimConfig::default()));
    assert_eq!(a.points, b.points);
    assert_eq!(a.image.as_raw(), b.image.as_raw());
    assert_eq!(a.objects, b.objects);
    assert_eq!(a.detections, b.detections);
    assert_eq!(a.calib, b.calib);
    let c = simulate_frame(12, 2, &SimConfig::default());
    assert_ne!(a.points.len(), c.points.len());
}

#[test]
fn frame_is_kitti_like() {
    let f = frame();
    assert!(
        f.points.len() > 90_000 && f.points.len() < 135_000,
        "{}",
        f.points.len()
    );
    assert_eq!(f.image.dimensions(), (1242, 375));
    for o in &f.objects {
        let b = o.bbox;
        assert!(
            b.x1 >= 0.0
                && b.y1 >= 0.0
                && b.x2 <= 1241.0
                && b.y2 <= 374.0
                && b.x2 > b.x1
                && b.y2 > b.y1
        );
        if o.class != ObjectClass::DontCare {
            assert!((0.0..=1.0).contains(&o.truncation));
            assert!((0..=3).contains(&o.occlusion));
            assert!(o.box3d.z > 0.0 && o.box3d.h > 0.0);
            assert!((-std::f64::consts::PI..=std::f64::consts::PI).contains(&o.alpha));
        }
    }
    assert!(f.objects.iter().any(|o| o.class == ObjectClass::Car));
}

/// A LiDAR point projected into the image lands on the surface it hit: same object
/// for points on labelled objects, same kind of surface for the rest. The LiDAR sits
/// 0.27 m behind and 0.08 m above the camera, so edges may disagree (parallax), and
/// beams that passed through foliage are exempt (the camera sees the leaves).
#[test]
fn points_project_onto_the_surface_they_hit() {
    let f = frame();
    let cam = f.calib.camera_model().unwrap();
    let (mut same_obj, mut obj) = (0, 0);
    let (mut same_kind, mut all) = (0, 0);
    for (p, info) in f.points.iter().zip(&f.point_info) {
        if info.through_foliage {
            continue;
        }
        let (u, v, depth) = cam.velo_to_image([p[0] as f64, p[1] as f64, p[2] as f64]);
        let (ui, vi) = (u.round(), v.round());
        if depth < 1.0 || ui < 0.0 || vi < 0.0 || ui > 1241.0 || vi > 374.0 {
            continue;
        }
        let seen = f.pixel_prim[(vi as usize) * 1242 + ui as usize];
        let hit = &f.scene.prims[info.prim as usize];
        all += 1;
        if seen != SKY {
            let s = &f.scene.prims[seen as usize];
            let kind = |x: Surface| match x {
                Surface::Road | Surface::Marking => 0,
                other => 1 + other as usize,
            };
            if kind(s.surface) == kind(hit.surface) {
                same_kind += 1;
            }
        }
        if hit.owner != fusiondet_sim::primitive::NO_OWNER {
            obj += 1;
            if seen != SKY && f.scene.prims[seen as usize].owner == hit.owner {
                same_obj += 1;
            }
        }
    }
    let obj_share = same_obj as f64 / obj as f64;
    let kind_share = same_kind as f64 / all as f64;
    eprintln!("object {obj_share:.4} ({obj}), kind {kind_share:.4} ({all})");
    assert!(obj > 500, "{obj}");
    assert!(
        obj_share > 0.95,
        "{same_obj} of {obj} object points land on their object"
    );
    assert!(
        kind_share > 0.95,
        "{same_kind} of {all} points land on their kind of surface"
    );
}

/// The dense depth (the truth of depth completion) agrees with the scan: a LiDAR return
/// projected into the image lies at about the depth the camera sees at that pixel, and
/// sky pixels have none.
#[test]
fn dense_depth_agrees_with_the_scan_and_is_empty_on_sky() {
    let f = frame();
    let (w, h) = f.image.dimensions();
    assert_eq!((f.depth.width, f.depth.height), (w as usize, h as usize));
    for (depth, prim) in f.depth.data.iter().zip(&f.pixel_prim) {
        assert_eq!(*depth == 0.0, *prim == SKY);
    }
    let cam = f.calib.camera_model().unwrap();
    let mut diffs: Vec<f64> = f
        .points
        .iter()
        .filter_map(|p| {
            let rect = cam.velo_to_rect([p[0] as f64, p[1] as f64, p[2] as f64]);
            let (u, v, _) = cam.rect_to_image(rect);
            let inside = rect[2] > 1.0 && u >= 0.0 && v >= 0.0 && u < w as f64 && v < h as f64;
            inside.then(|| {
                let seen = f.depth.get(u as usize, v as usize) as f64;
                (seen - rect[2]).abs() / rect[2]
            })
        })
        .collect();
    assert!(diffs.len() > 10_000, "{}", diffs.len());
    diffs.sort_by(f64::total_cmp);
    let median = diffs[diffs.len() / 2];
    assert!(median < 0.01, "median relative difference {median}");
}
