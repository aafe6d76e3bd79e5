//! The sparse depth image of a LiDAR scan: every point in front of the camera projected
//! through P2, its depth the rectified-camera z, the nearest point kept per pixel (the
//! pixel whose square contains the projection).

use fusiondet_dataset::SensorFrame;
use fusiondet_kitti::DepthMap;

/// Points nearer than this (rectified z, metres) are not projected.
const NEAR: f64 = 0.1;

/// The frame's scan as a sparse depth map of the image's size.
pub fn project_scan(frame: &SensorFrame) -> DepthMap {
    let (w, h) = (frame.image_size[0] as usize, frame.image_size[1] as usize);
    let mut map = DepthMap::empty(w, h);
    for p in &frame.lidar {
        let rect = frame
            .camera
            .velo_to_rect([p[0] as f64, p[1] as f64, p[2] as f64]);
        if rect[2] <= NEAR {
            continue;
        }
        let (u, v, _) = frame.camera.rect_to_image(rect);
        if !(u >= 0.0 && v >= 0.0 && u < w as f64 && v < h as f64) {
            continue;
        }
        let (x, y) = (u as usize, v as usize);
        let depth = rect[2] as f32;
        let old = map.get(x, y);
        if old == 0.0 || depth < old {
            map.set(x, y, depth);
        }
    }
    map
}

#[cfg(test)]
mod tests {
    use super::*;
    use fusiondet_kitti::FrameDir;
    use std::path::Path;

    #[test]
    fn a_projected_point_lands_on_its_pixel_at_its_depth() {
        let dir = FrameDir::new(
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../../data/kitti-sample/training"),
        );
        let mut frame = SensorFrame::load(&dir, "000001", false).unwrap();
        // Two points seen through one pixel's centre: the nearer wins; one behind the
        // camera is dropped.
        let (px, py) = (600usize, 200usize);
        let through = |depth| {
            frame
                .camera
                .image_to_rect(px as f64 + 0.5, py as f64 + 0.5, depth)
        };
        let (rect_far, rect_near) = (through(20.0), through(10.0));
        let to_velo = |r: [f64; 3]| frame.camera.rect_to_velo(r).map(|v| v as f32);
        let (far, near) = (to_velo(rect_far), to_velo(rect_near));
        let behind = to_velo([0.0, 0.0, -5.0]);
        frame.lidar = vec![
            [far[0], far[1], far[2], 0.0],
            [near[0], near[1], near[2], 0.0],
            [behind[0], behind[1], behind[2], 0.0],
        ];
        let map = project_scan(&frame);
        assert_eq!((map.width, map.height), (1242, 375));
        assert_eq!(map.valid_count(), 1);
        assert!(
            (map.get(px, py) as f64 - rect_near[2]).abs() < 1e-3,
            "{} vs {}",
            map.get(px, py),
            rect_near[2]
        );
        // The whole scan: thousands of pixels, all at plausible depths.
        let full = project_scan(&SensorFrame::load(&dir, "000001", false).unwrap());
        assert!(full.valid_count() > 10_000, "{}", full.valid_count());
        assert!(
            full.data
                .iter()
                .all(|&d| d == 0.0 || (0.1..120.0).contains(&d))
        );
    }
}
