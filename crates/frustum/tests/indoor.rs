//! The frustum family on SUN RGB-D scenes: the real scene 000017 read through
//! `fusiondet_dataset::indoor`.

use fusiondet_dataset::indoor::load_scene;
use fusiondet_dataset::{Class, DerivedFrame, InMemoryFrames};
use fusiondet_frustum::SliceStrategy;
use fusiondet_frustum::{
    FrameDetection, FrustumConfig, FrustumDataset, ProjectedFrame, extract_frustum,
};
use fusiondet_geometry::count_points_in_box;
use fusiondet_sunrgbd::{SunClass, SunRgbdDir};
use std::path::Path;

fn scene() -> ProjectedFrame {
    let dir = SunRgbdDir::new(Path::new(env!("CARGO_MANIFEST_DIR")).join("../sunrgbd/tests/data"));
    ProjectedFrame::derive(load_scene(&dir, "000017", true).unwrap()).unwrap()
}

#[test]
fn the_bed_frustum_holds_the_beds_points() {
    let frame = scene();
    let labels = fusiondet_sunrgbd::read_labels(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("../sunrgbd/tests/data/label/000017.txt"),
    )
    .unwrap();
    let bed = labels.iter().find(|o| o.class == "bed").unwrap();
    let oi = frame
        .classes
        .iter()
        .position(|c| *c == Class::SunRgbd(SunClass::Bed))
        .unwrap();
    let config = FrustumConfig::sun_rgbd();
    let fp = extract_frustum(&frame, &frame.objects[oi].bbox, config.depth_range, 0.0).unwrap();
    // The bed's points in the image's box, counted in upright depth.
    let b = fusiondet_geometry::Box2d {
        x2: bed.bbox.x2.min(frame.image_size[0]),
        y2: bed.bbox.y2.min(frame.image_size[1]),
        ..bed.bbox
    };
    let expected = frame
        .cloud
        .rect
        .iter()
        .zip(&frame.cloud.uv)
        .filter(|(r, uv)| {
            let up = [r[0], r[2], -r[1]];
            bed.box3d.contains(up)
                && (b.x1..=b.x2).contains(&uv[0])
                && (b.y1..=b.y2).contains(&uv[1])
        })
        .count();
    let gt = fp.frame.box_to_frustum(&frame.objects[oi].box3d);
    let got = count_points_in_box(&gt, &fp.points);
    assert!(expected > 100, "{expected}");
    assert_eq!(got, expected);
    // Every frustum point is in front of the camera within the room's depth range.
    assert!(fp.points.iter().all(|p| p[2] >= 0.0 && p[2] <= 8.0));
}

#[test]
fn labelled_frustums_learn_the_ten_classes_and_decode_back_to_the_label() {
    let frame = scene();
    let config = FrustumConfig::sun_rgbd();
    assert_eq!(config.classes.len(), 10);
    assert_eq!(
        config.slicing.slices_per_scale(config.depth_range),
        [80, 40, 20, 10]
    );
    let frames = InMemoryFrames::new(vec![frame.clone()]);
    let data = FrustumDataset::from_labels(frames, config.clone(), 3).unwrap();
    assert_eq!(data.len(), 2 * config.augment.copies, "{:?}", data.skips());
    for i in 0..data.len() {
        let s = data.sample(i, 3, 0).unwrap();
        let oi = data.specs()[i].object.unwrap();
        let slot = match frame.classes[oi] {
            Class::SunRgbd(c) => c.index(),
            Class::Kitti(_) => unreachable!(),
        };
        assert_eq!((s.class_slot, s.num_class_slots), (slot, 10));
        let t = s.target.as_ref().unwrap();
        let back = config.coder.decode_encoding(&t.encoding, &s.frame);
        let want = frame.objects[oi].box3d;
        for (a, b) in [
            (back.x, want.x),
            (back.y, want.y),
            (back.z, want.z),
            (back.l, want.l),
            (back.w, want.w),
            (back.h, want.h),
        ] {
            assert!((a - b).abs() < 1e-6, "{back:?} vs {want:?}");
        }
        let dr = fusiondet_geometry::normalize_angle(back.ry - want.ry);
        assert!(dr.abs() < 1e-6, "{back:?} vs {want:?}");
    }
    // Detection frustums from SUN RGB-D 2D detections; a KITTI class is not wanted.
    let det = |class, score| FrameDetection {
        frame_id: "000017".into(),
        class,
        bbox: frame.objects[1].bbox,
        score,
    };
    let frames = InMemoryFrames::new(vec![frame.clone()]);
    let d = FrustumDataset::from_detections(
        frames,
        &[
            det(Class::SunRgbd(SunClass::Bed), 0.9),
            det(Class::Kitti(fusiondet_kitti::ObjectClass::Car), 0.8),
        ],
        config,
    )
    .unwrap();
    assert_eq!(d.len(), 1);
    assert_eq!(d.specs()[0].class, Class::SunRgbd(SunClass::Bed));
}

#[test]
fn a_kitti_class_has_no_slot_in_the_indoor_set_and_saf_slicing_is_refused() {
    let mut c = FrustumConfig::sun_rgbd();
    c.classes = vec![fusiondet_kitti::ObjectClass::Car.into()];
    let e = c.validate().unwrap_err().to_string();
    assert!(e.contains("Car") && e.contains("bed"), "{e}");
    let c = FrustumConfig {
        slicing: FrustumConfig::saf_car().slicing,
        ..FrustumConfig::sun_rgbd()
    };
    let e = c.validate().unwrap_err().to_string();
    assert!(e.contains("mean height"), "{e}");
}
