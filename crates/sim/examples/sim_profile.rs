//! Times the stages of frame simulation in thread CPU time (one thread):
//! `cargo run --release -p fusiondet-sim --example sim_profile -- [frames]`.

use fusiondet_sim::rng::{Stream, frame_key, frame_sampler};
use fusiondet_sim::{SimConfig, camera, label, layout, lidar, sensors};

/// CPU time of this thread (ns), immune to other processes competing for the cores.
fn cpu_ns() -> u64 {
    std::fs::read_to_string("/proc/thread-self/schedstat")
        .ok()
        .and_then(|s| s.split_whitespace().next().and_then(|x| x.parse().ok()))
        .unwrap_or(0)
}

struct Instant(u64);
impl Instant {
    fn now() -> Instant {
        Instant(cpu_ns())
    }
    fn elapsed(&self) -> std::time::Duration {
        std::time::Duration::from_nanos(cpu_ns() - self.0)
    }
}

fn main() {
    let n: usize = std::env::args()
        .nth(1)
        .and_then(|a| a.parse().ok())
        .unwrap_or(10);
    let cfg = SimConfig::default();
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    pool.install(|| {
        let mut t = [0.0f64; 6];
        let mut prims = 0;
        for i in 0..n as u64 {
            let s0 = Instant::now();
            let (scene, _) =
                layout::build_scene(&mut frame_sampler(1, i, Stream::Layout), &cfg.layout);
            prims += scene.prims.len();
            let calib = sensors::sample_calib(&mut frame_sampler(1, i, Stream::Calib));
            let cam = calib.camera_model().unwrap();
            t[0] += s0.elapsed().as_secs_f64();
            let s1 = Instant::now();
            let scan = lidar::scan(&scene, &cfg.lidar, frame_key(1, i, Stream::Lidar));
            t[1] += s1.elapsed().as_secs_f64();
            let s2 = Instant::now();
            let mut cs = cfg.camera.clone();
            cs.shadows = false;
            let _r = camera::render(&scene, &cam, &cs);
            t[2] += s2.elapsed().as_secs_f64();
            let s3 = Instant::now();
            let render = camera::render(&scene, &cam, &cfg.camera);
            t[3] += s3.elapsed().as_secs_f64();
            let s4 = Instant::now();
            let views = label::label_frame(&scene, &cam, &render);
            t[4] += s4.elapsed().as_secs_f64();
            let s5 = Instant::now();
            let mut bytes = Vec::new();
            render
                .image
                .write_to(
                    &mut std::io::Cursor::new(&mut bytes),
                    image::ImageFormat::Png,
                )
                .unwrap();
            t[5] += s5.elapsed().as_secs_f64();
            std::hint::black_box((scan, views, bytes));
        }
        let names = [
            "layout+bvh",
            "lidar",
            "camera (no shadows)",
            "camera (shadows)",
            "labels",
            "png",
        ];
        for (k, name) in names.iter().enumerate() {
            println!("{name:>22}: {:7.1} ms/frame", 1000.0 * t[k] / n as f64);
        }
        println!("mean primitives {}", prims / n);
    });
}
