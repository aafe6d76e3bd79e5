//! F-ConvNet's box coder, the one every step uses: the training targets, the loss and
//! the decoding of network outputs into boxes. Built from the configuration (heading
//! bins from `[model] num_heading_bins`, one size cluster per class of the data set's
//! [`ClassSet`] with its mean size), so a changed bin count or class set changes all
//! three at once.
//!
//! Encoding of a ground-truth box in a frustum frame (see [`crate::FrustumFrame`]):
//! - centre: the geometric centre (KITTI bottom y − h/2) in the frustum frame; the
//!   network predicts it as an offset from each output position's centre;
//! - heading: the frustum-frame heading ry_f = ry − φ (mirrored: π − (ry − φ)) in
//!   `heading_bins` bins over 2π, bin k centred at k·2π/bins (bin 0 centred at 0),
//!   residual = heading − bin centre in radians, in [−π/bins, π/bins);
//! - size: cluster = the class's slot in the class set, residual = (size − mean) / mean
//!   for (l, w, h).

use crate::frustum::FrustumFrame;
use fusiondet_dataset::ClassSet;
use fusiondet_geometry::{Box3d, normalize_angle};
use std::f64::consts::TAU;

/// Heading bins and size clusters.
#[derive(Debug, Clone, PartialEq)]
pub struct BoxCoder {
    heading_bins: usize,
    classes: ClassSet,
}

impl Default for BoxCoder {
    /// F-ConvNet's KITTI coder: 12 heading bins, Car / Pedestrian / Cyclist clusters.
    fn default() -> Self {
        BoxCoder::kitti()
    }
}

impl BoxCoder {
    /// A coder with `heading_bins` bins and one size cluster per class of `classes`.
    pub fn new(heading_bins: usize, classes: ClassSet) -> Result<BoxCoder, String> {
        if heading_bins == 0 {
            return Err("the box coder needs at least one heading bin".into());
        }
        if classes.is_empty() {
            return Err("the box coder needs at least one class".into());
        }
        if let Some(c) = classes
            .classes
            .iter()
            .find(|c| c.mean_size.iter().any(|s| !(s.is_finite() && *s > 0.0)))
        {
            return Err(format!(
                "class {}: mean size must be finite and positive",
                c.name
            ));
        }
        Ok(BoxCoder {
            heading_bins,
            classes,
        })
    }

    /// F-ConvNet's KITTI coder: 12 heading bins, Car / Pedestrian / Cyclist clusters.
    pub fn kitti() -> BoxCoder {
        BoxCoder {
            heading_bins: 12,
            classes: ClassSet::kitti(),
        }
    }

    pub fn heading_bins(&self) -> usize {
        self.heading_bins
    }

    /// The class set whose slots are the one-hot and the size clusters.
    pub fn classes(&self) -> &ClassSet {
        &self.classes
    }

    pub fn num_clusters(&self) -> usize {
        self.classes.len()
    }

    /// The size cluster (and one-hot slot) of a class; `None` for classes without one.
    pub fn cluster_of(&self, class: &str) -> Option<usize> {
        self.classes.index_of(class)
    }

    /// Mean (l, w, h) of cluster `k`.
    pub fn mean_size(&self, k: usize) -> [f64; 3] {
        self.classes.classes[k].mean_size
    }

    /// Every cluster's mean size in f32, as the network's loss uses them.
    pub fn mean_sizes_f32(&self) -> Vec<[f32; 3]> {
        self.classes
            .mean_sizes()
            .iter()
            .map(|m| m.map(|v| v as f32))
            .collect()
    }

    /// A heading as (bin, residual): residual = heading − bin·2π/bins in [−π/bins, π/bins).
    pub fn heading_to_bin(&self, heading: f64) -> (usize, f64) {
        let width = TAU / self.heading_bins as f64;
        let shifted = (heading + 0.5 * width).rem_euclid(TAU);
        let bin = ((shifted / width) as usize).min(self.heading_bins - 1);
        (bin, shifted - (bin as f64 + 0.5) * width)
    }

    /// The inverse of [`BoxCoder::heading_to_bin`], wrapped to (−π, π].
    pub fn bin_to_heading(&self, bin: usize, residual: f64) -> f64 {
        normalize_angle(bin as f64 * TAU / self.heading_bins as f64 + residual)
    }

    /// Width of one heading bin in radians, in the network's f32.
    pub fn heading_bin_width_f32(&self) -> f32 {
        std::f32::consts::TAU / self.heading_bins as f32
    }

    /// [`BoxCoder::heading_to_bin`] in the network's f32 (synthetic targets, tests).
    pub fn heading_to_bin_f32(&self, angle: f32) -> (usize, f32) {
        let width = self.heading_bin_width_f32();
        let shifted = (angle + width / 2.0).rem_euclid(std::f32::consts::TAU);
        let bin = ((shifted / width) as usize).min(self.heading_bins - 1);
        (bin, shifted - (bin as f32 * width + width / 2.0))
    }

    /// [`BoxCoder::bin_to_heading`] in the network's f32, wrapped to (−π, π].
    pub fn bin_to_heading_f32(&self, bin: usize, residual: f32) -> f32 {
        use std::f32::consts::{PI, TAU};
        let a = (bin as f32 * TAU / self.heading_bins as f32 + residual).rem_euclid(TAU);
        if a > PI { a - TAU } else { a }
    }

    /// Encodes a KITTI camera-frame box in `frame` with size cluster `size_cluster`
    /// (see [`BoxCoder::cluster_of`]; panics if it is not a cluster).
    pub fn encode_box(&self, gt: &Box3d, size_cluster: usize, frame: &FrustumFrame) -> BoxEncoding {
        let mean = self.mean_size(size_cluster);
        let f = frame.box_to_frustum(gt);
        let (heading_bin, heading_residual) = self.heading_to_bin(f.ry);
        BoxEncoding {
            center: [f.x, f.y - 0.5 * f.h, f.z],
            heading_bin,
            heading_residual,
            size_cluster,
            size_residual: [
                (f.l - mean[0]) / mean[0],
                (f.w - mean[1]) / mean[1],
                (f.h - mean[2]) / mean[2],
            ],
        }
    }

    /// Turns network outputs into a KITTI camera-frame box (bottom-centre location,
    /// `ry` wrapped to (−π, π]): centre = `position_center + predicted.center` (the
    /// network regresses the centre as an offset from its output position) in the
    /// frustum frame, heading from bin and residual, size = mean · (1 + residual).
    /// `frustum_rotation` is the sample's frame ([`crate::FrustumSample::frame`]), which
    /// also undoes any training mirror or depth shift.
    pub fn decode_box(
        &self,
        position_center: [f64; 3],
        predicted: &BoxEncoding,
        frustum_rotation: &FrustumFrame,
    ) -> Box3d {
        let BoxEncoding {
            center: center_offset,
            heading_bin,
            heading_residual,
            size_cluster,
            size_residual,
        } = *predicted;
        let mean = self.mean_size(size_cluster);
        let [l, w, h] = [0, 1, 2].map(|k| mean[k] * (1.0 + size_residual[k]));
        let c = [0, 1, 2].map(|k| position_center[k] + center_offset[k]);
        let in_frustum = Box3d {
            h,
            w,
            l,
            x: c[0],
            y: c[1] + 0.5 * h,
            z: c[2],
            ry: self.bin_to_heading(heading_bin, heading_residual),
        };
        frustum_rotation.box_to_rect(&in_frustum)
    }

    /// [`BoxCoder::decode_box`] of an encoding (the position at the origin, the offset the centre).
    pub fn decode_encoding(&self, e: &BoxEncoding, frame: &FrustumFrame) -> Box3d {
        self.decode_box([0.0; 3], e, frame)
    }
}

/// What the network regresses for one ground-truth box.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BoxEncoding {
    /// Geometric centre in the frustum frame.
    pub center: [f64; 3],
    pub heading_bin: usize,
    pub heading_residual: f64,
    pub size_cluster: usize,
    /// (l, w, h) residual over the cluster's mean size.
    pub size_residual: [f64; 3],
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_data::sample_camera;
    use fusiondet_kitti::ObjectClass;
    use proptest::prelude::*;
    use std::f64::consts::PI;

    #[test]
    fn heading_bins_cover_the_circle() {
        let coder = BoxCoder::kitti();
        let w = TAU / 12.0;
        assert_eq!(coder.heading_to_bin(0.0), (0, 0.0));
        let (b, r) = coder.heading_to_bin(w);
        assert_eq!(b, 1);
        assert!(r.abs() < 1e-12);
        assert_eq!(coder.heading_to_bin(-0.1).0, 0);
        assert_eq!(coder.heading_to_bin(PI).0, 6);
        assert_eq!(coder.heading_to_bin(-PI + 1e-9).0, 6);
        assert_eq!(coder.heading_to_bin(-w).0, 11);
        for i in 0..1000 {
            let a = -PI + TAU * i as f64 / 1000.0;
            let (b, r) = coder.heading_to_bin(a);
            assert!(
                b < 12 && (-0.5 * w..0.5 * w + 1e-12).contains(&r),
                "{a} -> {b} {r}"
            );
            assert!(normalize_angle(coder.bin_to_heading(b, r) - a).abs() < 1e-12);
        }
    }

    fn arb_box() -> impl Strategy<Value = Box3d> {
        (
            -20.0..20.0f64,
            0.5..2.5f64,
            1.0..70.0f64,
            -PI..PI,
            0.3..5.0f64,
            0.3..2.5f64,
            0.5..2.5f64,
        )
            .prop_map(|(x, y, z, ry, l, w, h)| Box3d {
                h,
                w,
                l,
                x,
                y,
                z,
                ry,
            })
    }

    proptest! {
        #[test]
        fn encode_decode_round_trip(
            b in arb_box(), cluster in 0usize..3, u in 0.0..1242.0f64, v in 0.0..375.0f64,
            mirrored in any::<bool>(), shift in -4.0..4.0f64,
            position in (-1.0..1.0f64, -1.0..2.0f64, 0.0..70.0f64),
        ) {
            let frame = FrustumFrame::through_pixel(&sample_camera(), u, v).with_augmentation(mirrored, shift);
            let coder = BoxCoder::kitti();
            let e = coder.encode_box(&b, cluster, &frame);
            prop_assert!(e.heading_bin < coder.heading_bins());
            let check = |d: Box3d| {
                let ok = [(d.x, b.x), (d.y, b.y), (d.z, b.z), (d.l, b.l), (d.w, b.w), (d.h, b.h)]
                    .iter()
                    .all(|(p, q)| (p - q).abs() < 1e-9)
                    && normalize_angle(d.ry - b.ry).abs() < 1e-9;
                (ok, d)
            };
            let (ok, d) = check(coder.decode_encoding(&e, &frame));
            prop_assert!(ok, "{d:?} vs {b:?}");
            // The same through a position centre and an offset from it.
            let p = [position.0, position.1, position.2];
            let off = [0, 1, 2].map(|k| e.center[k] - p[k]);
            let (ok, d) = check(coder.decode_box(p, &BoxEncoding { center: off, ..e }, &frame));
            prop_assert!(ok, "{d:?} vs {b:?}");
            // The encoded centre is the geometric centre: bottom y − h/2 in the frame.
            let bottom = frame.to_frustum([b.x, b.y, b.z]);
            prop_assert!((e.center[1] - (bottom[1] - 0.5 * b.h)).abs() < 1e-12);
        }
    }

    #[test]
    fn size_encoding_is_relative_to_the_class_mean() {
        let coder = BoxCoder::kitti();
        let frame = FrustumFrame::through_pixel(&sample_camera(), 600.0, 180.0);
        let m = coder.mean_size(0);
        assert!(
            (m[0] - 3.883).abs() < 5e-4
                && (m[1] - 1.629).abs() < 5e-4
                && (m[2] - 1.526).abs() < 5e-4
        );
        let b = Box3d {
            h: m[2],
            w: m[1] * 1.1,
            l: m[0] * 0.5,
            x: 0.0,
            y: 1.6,
            z: 20.0,
            ry: 0.0,
        };
        let e = coder.encode_box(&b, 0, &frame);
        assert!(
            (e.size_residual[0] + 0.5).abs() < 1e-12
                && (e.size_residual[1] - 0.1).abs() < 1e-12
                && e.size_residual[2].abs() < 1e-12
        );
        assert_eq!(coder.cluster_of(ObjectClass::Cyclist.as_str()), Some(2));
        assert_eq!(coder.cluster_of(ObjectClass::Van.as_str()), None);
    }

    #[test]
    fn f32_heading_round_trip() {
        let coder = BoxCoder::kitti();
        for i in 0..100 {
            let a = -std::f32::consts::PI + 0.0628 * i as f32 + 0.001;
            let (bin, res) = coder.heading_to_bin_f32(a);
            assert!(
                bin < 12 && res.abs() <= std::f32::consts::PI / 12.0 + 1e-5,
                "{a} {bin} {res}"
            );
            let back = coder.bin_to_heading_f32(bin, res);
            assert!((back - a).abs() < 1e-4, "{a} → {back}");
        }
        assert_eq!(coder.heading_to_bin_f32(0.0).0, 0);
        assert_eq!(coder.heading_to_bin_f32(std::f32::consts::PI / 2.0).0, 3);
    }

    #[test]
    fn a_coder_follows_its_configuration() {
        let eight = BoxCoder::new(8, ClassSet::kitti()).unwrap();
        assert_eq!(eight.heading_to_bin(TAU / 8.0).0, 1);
        assert_eq!(eight.heading_to_bin(PI).0, 4);
        assert!(BoxCoder::new(0, ClassSet::kitti()).is_err());
        let mut bad = ClassSet::kitti();
        bad.classes[1].mean_size[2] = 0.0;
        let err = BoxCoder::new(12, bad).unwrap_err();
        assert!(err.contains("Pedestrian"), "{err}");
    }
}
