//! Renders a bundled frame with its labels as fake detections (plus a made-up car half
//! behind the camera), for looking at the picture:
//! `cargo run -p fusiondet-viz --example render_sample -- 000001 /tmp/frame.png`.

use fusiondet_kitti::{FrameDir, image::write_png};
use fusiondet_viz::{RenderOptions, load_frame, render_frame_with};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let id = args.get(1).map_or("000001", String::as_str);
    let out = args.get(2).map_or("/tmp/frame.png", String::as_str);
    let frames = FrameDir::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../data/kitti-sample/training"
    ));
    let mut view = load_frame(&frames, id, None)?;
    // Fake detections: labels nudged and rotated a little, with made-up scores.
    let dets = view
        .ground_truth
        .iter()
        .enumerate()
        .map(|(i, o)| {
            let mut d = o.clone();
            d.box3d.x += 0.4;
            d.box3d.z += 0.8;
            d.box3d.ry += 0.15;
            d.score = Some(0.95 - 0.1 * i as f64);
            d
        })
        .collect::<Vec<_>>();
    // A made-up car beside the ego reaching behind the camera, to show near-plane clipping.
    let mut dets = dets;
    if let Some(first) = view.ground_truth.first() {
        let mut side = first.clone();
        side.class = fusiondet_kitti::ObjectClass::Car;
        side.box3d = fusiondet_kitti::Box3d {
            h: 1.5,
            w: 1.8,
            l: 4.5,
            x: 3.5,
            y: 1.7,
            z: 1.0,
            ry: 1.57,
        };
        side.score = Some(0.5);
        dets.push(side);
    }
    view.detections = Some(dets);
    let start = std::time::Instant::now();
    let img = render_frame_with(&view, &RenderOptions::default());
    eprintln!(
        "rendered {}x{} in {:?}",
        img.width(),
        img.height(),
        start.elapsed()
    );
    write_png(std::path::Path::new(out), &img)?;
    // Optional `X Y W H`: also write that region enlarged 2x, to check small text.
    if let [x, y, w, h] = args.get(3..7).unwrap_or(&[]) {
        let [x, y, w, h] = [x, y, w, h].map(|v| v.parse::<u32>().unwrap_or(0));
        let region = image::imageops::crop_imm(&img, x, y, w, h).to_image();
        let big =
            image::imageops::resize(&region, 2 * w, 2 * h, image::imageops::FilterType::Nearest);
        write_png(std::path::Path::new(&format!("{out}.crop.png")), &big)?;
    }
    Ok(())
}
