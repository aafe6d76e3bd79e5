//! End-to-end tests of `fusiondet view`: the pages it writes, its refusals, and — where
//! Chromium is installed — what a real browser draws from them (headless, software WebGL):
//! screenshots whose pixels must show the boxes and points where the page says it drew
//! them. Without Chromium the browser test says so and passes.

use fusiondet_viz::image::{Rgb, RgbImage};
use std::path::{Path, PathBuf};
use std::process::Command;

mod common;
use common::{assert_fails_with, repo_root, run, s};

fn training_dir() -> PathBuf {
    repo_root().join("data/kitti-sample/training")
}

fn view(args: &[&str]) -> String {
    let o = run("view", args);
    let out = common::all_output(&o);
    assert!(o.status.success(), "view {args:?} failed:\n{out}");
    out
}

/// The `#frame-data` JSON of a page.
fn data_of(page: &Path) -> serde_json::Value {
    let html = std::fs::read_to_string(page).unwrap();
    let start = html.find("type=\"application/json\">").unwrap() + 24;
    let end = start + html[start..].find("</script>").unwrap();
    serde_json::from_str(&html[start..end]).unwrap()
}

#[test]
fn a_page_of_a_bundled_frame_is_one_small_self_contained_file() {
    let dir = tempfile::tempdir().unwrap();
    let page = dir.path().join("frame.html");
    let out = view(&[
        "--data-dir",
        s(&training_dir()),
        "--id",
        "1",
        "--out",
        s(&page),
    ]);
    assert!(out.contains("wrote"), "{out}");
    let size = std::fs::metadata(&page).unwrap().len();
    assert!(size < 5_000_000, "{size} bytes");
    let html = std::fs::read_to_string(&page).unwrap();
    // Nothing is fetched: every script is inline.
    assert!(!html.contains("<script src"), "an external script");
    assert!(!html.contains("src=\"http") && !html.contains("href=\"http"));
    let data = data_of(&page);
    assert_eq!(data["id"], "000001");
    assert_eq!(data["boxes"].as_array().unwrap().len(), 3);
    assert_eq!(data["dontcare"].as_array().unwrap().len(), 4);
    assert!(data["lidar"]["count"].as_u64().unwrap() > 10_000);
}

#[test]
fn a_split_gets_an_index_and_links_between_neighbours_and_is_replaced_only_when_asked() {
    let dir = tempfile::tempdir().unwrap();
    let out_dir = dir.path().join("pages");
    let data = training_dir();
    let args = [
        "--data-dir",
        s(&data),
        "--split",
        "val",
        "--out-dir",
        s(&out_dir),
    ];
    view(&args);
    let index = std::fs::read_to_string(out_dir.join("index.html")).unwrap();
    let val = ["000001", "000002", "000004", "000005", "000134"];
    for id in val {
        assert!(index.contains(&format!("href=\"{id}.html\"")), "{id}");
    }
    let nav = &data_of(&out_dir.join("000002.html"))["nav"];
    assert_eq!(nav["prev"], "000001.html");
    assert_eq!(nav["next"], "000004.html");
    assert_eq!(nav["index"], "index.html");
    assert!(data_of(&out_dir.join("000001.html"))["nav"]["prev"].is_null());
    // An earlier view's pages are replaced only with --force.
    assert_fails_with("view", &args, "pass --force");
    let mut forced = args.to_vec();
    forced.push("--force");
    view(&forced);
    // A directory of somebody else's files is never written into.
    let foreign = dir.path().join("mine");
    std::fs::create_dir(&foreign).unwrap();
    std::fs::write(foreign.join("notes.txt"), "keep").unwrap();
    let mut into_foreign = args.to_vec();
    into_foreign[5] = s(&foreign);
    into_foreign.push("--force");
    assert_fails_with("view", &into_foreign, "did not write");
    assert_eq!(
        std::fs::read_to_string(foreign.join("notes.txt")).unwrap(),
        "keep"
    );
}

#[test]
fn bad_input_gets_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let page = dir.path().join("p.html");
    let data = s(&training_dir()).to_string();
    let p = s(&page).to_string();
    assert_fails_with(
        "view",
        &["--data-dir", &data, "--id", "999999", "--out", &p],
        "image_2/999999.png",
    );
    assert_fails_with(
        "view",
        &["--data-dir", &data, "--id", "../1", "--out", &p],
        "not a frame id",
    );
    // Frame 000001 into `p`, with further arguments.
    let frame_one = |extra: &[&str], needle: &str| {
        let args = [
            &[
                "--data-dir",
                data.as_str(),
                "--id",
                "1",
                "--out",
                p.as_str(),
            ],
            extra,
        ];
        assert_fails_with("view", &args.concat(), needle);
    };
    frame_one(&["--max-points", "0"], "--max-points");
    assert_fails_with(
        "view",
        &["--data-dir", &data, "--split", "nosuch", "--out-dir", &p],
        "no such id list",
    );
    let empty = tempfile::tempdir().unwrap();
    frame_one(&["--pseudo-dir", s(empty.path())], "000001.bin");
    // Never over an input: the page may not replace the frame's own label file.
    let copy = tempfile::tempdir().unwrap();
    let label = copy.path().join("label_2/000001.txt");
    std::fs::create_dir_all(label.parent().unwrap()).unwrap();
    std::fs::write(&label, "kept").unwrap();
    for sub in ["image_2", "calib", "velodyne"] {
        let (from, to) = (training_dir().join(sub), copy.path().join(sub));
        std::fs::create_dir_all(&to).unwrap();
        for entry in std::fs::read_dir(from).unwrap().flatten() {
            std::fs::copy(entry.path(), to.join(entry.file_name())).unwrap();
        }
    }
    assert_fails_with(
        "view",
        &[
            "--data-dir",
            s(copy.path()),
            "--id",
            "1",
            "--out",
            s(&label),
        ],
        "would overwrite an input",
    );
    assert_eq!(std::fs::read_to_string(&label).unwrap(), "kept");
    assert!(!page.exists());
}

// ---------------------------------------------------------------- the browser test

/// Chromium, if installed (`CHROMIUM` names another binary).
fn chromium() -> Option<PathBuf> {
    if let Some(p) = std::env::var_os("CHROMIUM") {
        return Some(PathBuf::from(p));
    }
    ["chromium", "chromium-browser", "google-chrome"]
        .iter()
        .flat_map(|name| {
            std::env::var_os("PATH")
                .map(|paths| std::env::split_paths(&paths).collect::<Vec<_>>())
                .unwrap_or_default()
                .into_iter()
                .map(move |dir| dir.join(name))
        })
        .find(|p| p.is_file())
}

const WINDOW: (u32, u32) = (1400, 800);

/// Headless Chromium on `page#probe<view>`: with `--screenshot` or `--dump-dom`
/// (the flags of `scripts/view-screenshot.sh`).
fn browse(browser: &Path, page: &Path, view: &str, action: &str) -> std::process::Output {
    let profile = tempfile::tempdir().unwrap();
    Command::new(browser)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--enable-unsafe-swiftshader",
            "--use-angle=swiftshader",
            "--disable-quic",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--disable-dev-shm-usage",
            "--hide-scrollbars",
            &format!("--user-data-dir={}", profile.path().display()),
            &format!("--window-size={},{}", WINDOW.0, WINDOW.1),
            "--virtual-time-budget=10000",
            action,
            &format!(
                "file://{}#probe{view}",
                page.canonicalize().unwrap().display()
            ),
        ])
        .output()
        .expect("run chromium")
}

/// The screenshot and the page's own record of where it drew things.
fn shoot(browser: &Path, page: &Path, view: &str, png: &Path) -> (RgbImage, serde_json::Value) {
    let o = browse(
        browser,
        page,
        view,
        &format!("--screenshot={}", png.display()),
    );
    assert!(png.is_file(), "no screenshot: {}", common::all_output(&o));
    let image = fusiondet_viz::image::open(png).unwrap().to_rgb8();
    let dom = common::text(&browse(browser, page, view, "--dump-dom").stdout);
    let start = dom.find("<pre id=\"probe\"").expect("no probe element");
    let start = start + dom[start..].find('>').unwrap() + 1;
    let end = start + dom[start..].find("</pre>").unwrap();
    let json = dom[start..end]
        .replace("&quot;", "\"")
        .replace("&amp;", "&");
    assert!(
        !json.is_empty(),
        "the page recorded nothing (did its script run?)"
    );
    (image, serde_json::from_str(&json).unwrap())
}

fn hex(c: &str) -> Rgb<u8> {
    let v = u32::from_str_radix(c.trim_start_matches('#'), 16).unwrap();
    Rgb([(v >> 16) as u8, (v >> 8) as u8, v as u8])
}

fn close(a: Rgb<u8>, b: Rgb<u8>, tolerance: i32) -> bool {
    (0..3).all(|k| (i32::from(a[k]) - i32::from(b[k])).abs() <= tolerance)
}

/// Whether a pixel within `radius` of (x, y) has colour `c`.
fn drawn_near(img: &RgbImage, x: f64, y: f64, radius: i64, c: Rgb<u8>, tolerance: i32) -> bool {
    let (x, y) = (x.round() as i64, y.round() as i64);
    (-radius..=radius).any(|dy| {
        (-radius..=radius).any(|dx| {
            let (px, py) = (x + dx, y + dy);
            px >= 0
                && py >= 0
                && (px as u32) < img.width()
                && (py as u32) < img.height()
                && close(*img.get_pixel(px as u32, py as u32), c, tolerance)
        })
    })
}

/// Share of the probed places where the colour is found.
fn hit_rate(img: &RgbImage, places: &[(f64, f64, Rgb<u8>)], tolerance: i32) -> f64 {
    let hits = places
        .iter()
        .filter(|&&(x, y, c)| drawn_near(img, x, y, 2, c, tolerance))
        .count();
    hits as f64 / places.len().max(1) as f64
}

/// Checks a screenshot against the probe: box edges in the 3D view and on the image in
/// their colours, points in theirs; returns (boxes by kind, points probed).
fn check_drawn(img: &RgbImage, probe: &serde_json::Value, what: &str) -> (Vec<String>, usize) {
    let mut scene_edges = Vec::new();
    let mut image_edges = Vec::new();
    let mut kinds = Vec::new();
    for b in probe["boxes"].as_array().unwrap() {
        let c = hex(b["colour"].as_str().unwrap());
        kinds.push(b["kind"].as_str().unwrap().to_string());
        for (list, key) in [(&mut scene_edges, "scene"), (&mut image_edges, "image")] {
            for p in b[key].as_array().unwrap() {
                list.push((p[0].as_f64().unwrap(), p[1].as_f64().unwrap(), c));
            }
        }
    }
    assert!(scene_edges.len() >= 12, "{what}: too few box edges in view");
    let scene = hit_rate(img, &scene_edges, 60);
    assert!(
        scene >= 0.9,
        "{what}: box edges drawn at {scene:.2} of their places"
    );
    let image = hit_rate(img, &image_edges, 60);
    assert!(
        image >= 0.9,
        "{what}: image edges drawn at {image:.2} of their places"
    );
    let points: Vec<(f64, f64, Rgb<u8>)> = probe["points"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| {
            let c = |k: usize| (p[k].as_f64().unwrap() * 255.0).round() as u8;
            (
                p[0].as_f64().unwrap(),
                p[1].as_f64().unwrap(),
                Rgb([c(2), c(3), c(4)]),
            )
        })
        .collect();
    assert!(
        points.len() >= 50,
        "{what}: {} points in view",
        points.len()
    );
    let drawn = hit_rate(img, &points, 40);
    assert!(
        drawn >= 0.7,
        "{what}: points drawn at {drawn:.2} of their places"
    );
    // And the rest of the 3D view is background: the checks above are not satisfied by
    // a page that paints everything.
    let bg = hex(probe["background"].as_str().unwrap());
    let r = &probe["scene"];
    let (x0, y0) = (r[0].as_f64().unwrap() as u32, r[1].as_f64().unwrap() as u32);
    let (w, h) = (r[2].as_f64().unwrap() as u32, r[3].as_f64().unwrap() as u32);
    let background = (y0..(y0 + h).min(img.height()))
        .flat_map(|y| (x0..(x0 + w).min(img.width())).map(move |x| (x, y)))
        .filter(|&(x, y)| close(*img.get_pixel(x, y), bg, 4))
        .count();
    let share = background as f64 / f64::from(w * h);
    assert!(
        (0.5..0.995).contains(&share),
        "{what}: background {share:.3}"
    );
    (kinds, points.len())
}

/// A simulated frame with its scan's pseudo points and detections (the labels moved 1.6 m
/// sideways, scores 0.9, 0.8, …), in `dir`.
fn simulated_frame(dir: &Path) -> (PathBuf, PathBuf, PathBuf) {
    let data = dir.join("sim");
    let o = run(
        "simulate",
        &["--out", s(&data), "--frames", "2", "--seed", "4"],
    );
    assert!(o.status.success(), "{}", common::all_output(&o));
    let training = data.join("training");
    let pseudo = dir.join("pseudo");
    let o = run(
        "pseudo-points",
        &[
            "--data-dir",
            s(&training),
            "--out-dir",
            s(&pseudo),
            "--ids",
            "000000",
        ],
    );
    assert!(o.status.success(), "{}", common::all_output(&o));
    let results = dir.join("results");
    std::fs::create_dir(&results).unwrap();
    let labels = fusiondet_kitti::read_objects(&training.join("label_2/000000.txt")).unwrap();
    let detections: Vec<_> = labels
        .into_iter()
        .filter(|o| o.class == fusiondet_kitti::ObjectClass::Car)
        .enumerate()
        .map(|(i, mut o)| {
            o.box3d.x += 1.6;
            o.score = Some(0.9 - 0.1 * i as f64);
            o
        })
        .collect();
    assert!(!detections.is_empty(), "the simulated frame has no car");
    fusiondet_kitti::write_objects(&results.join("000000.txt"), &detections).unwrap();
    (training, pseudo, results)
}

#[test]
fn pages_draw_points_and_boxes_in_a_real_browser() {
    let Some(browser) = chromium() else {
        eprintln!(
            "skipped: no Chromium installed (Debian: apt-get install chromium); the pages \
             were not opened in a browser"
        );
        return;
    };
    // Screenshots stay in the target directory for a person to look at.
    let shots = Path::new(env!("CARGO_TARGET_TMPDIR")).join("view-screenshots");
    std::fs::create_dir_all(&shots).unwrap();
    let dir = tempfile::tempdir().unwrap();

    // A real KITTI frame: ground truth only.
    let real = dir.path().join("real.html");
    view(&[
        "--data-dir",
        s(&training_dir()),
        "--id",
        "1",
        "--out",
        s(&real),
    ]);
    let (img, probe) = shoot(&browser, &real, "", &shots.join("real-000001.png"));
    let (kinds, _) = check_drawn(&img, &probe, "real frame");
    assert_eq!(kinds, ["gt"; 3]);
    let (img, probe) = shoot(&browser, &real, "-bev", &shots.join("real-000001-bev.png"));
    check_drawn(&img, &probe, "real frame, bird's-eye view");

    // A simulated frame with detections and pseudo points.
    let (training, pseudo, results) = simulated_frame(dir.path());
    let sim = dir.path().join("sim.html");
    let frame: [&str; 8] = [
        "--data-dir",
        s(&training),
        "--id",
        "0",
        "--result-dir",
        s(&results),
        "--pseudo-dir",
        s(&pseudo),
    ];
    view(&[&frame[..], &["--out", s(&sim)]].concat());
    let (img, probe) = shoot(&browser, &sim, "-bev", &shots.join("sim-000000-bev.png"));
    let (kinds, _) = check_drawn(&img, &probe, "simulated frame");
    let orange = hex(data_of(&sim)["colours"]["det"].as_str().unwrap());
    let det_edges: Vec<(f64, f64, Rgb<u8>)> = probe["boxes"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|b| b["kind"] == "det")
        .flat_map(|b| b["scene"].as_array().unwrap().clone())
        .map(|p| (p[0].as_f64().unwrap(), p[1].as_f64().unwrap(), orange))
        .collect();
    assert!(kinds.contains(&"gt".to_string()) && kinds.contains(&"det".to_string()));
    assert!(data_of(&sim)["pseudo"]["count"].as_u64().unwrap() > 1000);
    shoot(&browser, &sim, "", &shots.join("sim-000000.png"));

    // The score slider starts above every score: no detection is drawn.
    let high = dir.path().join("high.html");
    view(
        &[
            &frame[..],
            &["--out", s(&high), "--score-threshold", "0.95"],
        ]
        .concat(),
    );
    let (img, probe) = shoot(
        &browser,
        &high,
        "-bev",
        &shots.join("sim-000000-hidden.png"),
    );
    let (kinds, _) = check_drawn(&img, &probe, "simulated frame, threshold 0.95");
    assert!(kinds.iter().all(|k| k == "gt"), "{kinds:?}");
    // Where the detections were drawn, no orange now (exactly: lines are antialiased).
    let left = hit_rate(&img, &det_edges, 0);
    assert!(
        left < 0.2,
        "detection colour still at {left:.2} of their edges"
    );
    eprintln!("screenshots in {}", shots.display());
}
