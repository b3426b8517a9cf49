//! `infer eval-points` on real photographs: York Urban's indoor images with
//! their derived junctions (read from the shared data folder beside the
//! repository, skipped without it), and its refusals.

use std::path::PathBuf;
use std::process::Command;

fn manifest_dir() -> PathBuf {
    std::env::var_os("CARGO_MANIFEST_DIR").map_or_else(|| env!("CARGO_MANIFEST_DIR").into(), Into::into)
}

fn infer(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_infer")).args(args).env("CI", "true").output().expect("runs")
}

#[test]
fn the_shipped_detector_and_the_classic_corners_are_scored_on_york_urban_photos() {
    let york = manifest_dir().join("../../shared/data/york_urban_lines");
    if !york.is_dir() {
        eprintln!("skipped: {} is not here", york.display());
        return;
    }
    // Two indoor photographs (a corridor, a room) and one without labels, which is skipped.
    let dir = tempfile::tempdir().unwrap();
    let images = dir.path().join("images");
    std::fs::create_dir(&images).unwrap();
    for name in ["P1020826", "P1020830"] {
        std::fs::copy(york.join(format!("images/{name}.jpg")), images.join(format!("{name}.jpg"))).unwrap();
    }
    std::fs::write(images.join("notes.txt"), "not a photo").unwrap();
    let checkpoint = manifest_dir().join("../checkpoints/faster-rcnn");
    let (c, i, p) = (checkpoint.to_str().unwrap(), images.to_str().unwrap(), york.join("junctions_derived"));
    let out = infer(&["eval-points", "--checkpoint", c, "--images", i, "--points", p.to_str().unwrap(), "--json"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(report["images"], 2);
    let methods = report["methods"].as_array().unwrap();
    let names: Vec<&str> = methods.iter().map(|m| m["method"].as_str().unwrap()).collect();
    assert_eq!(names, ["detector", "shi-tomasi", "harris", "random"]);
    let labels = methods[0]["labels"].as_u64().unwrap();
    assert!(labels > 50, "{labels} junctions on two photos");
    // The baselines get the detector's count (fewer only where a photo has fewer corners).
    let detector_points = methods[0]["points"].as_u64().unwrap();
    assert!(detector_points > 0);
    assert_eq!(methods[3]["points"].as_u64().unwrap(), detector_points);
    for m in &methods[1..3] {
        assert!(m["points"].as_u64().unwrap() <= detector_points, "{m}");
    }
    // Corners of a real room are where junctions are far more often than random points.
    let precision = |k: usize| methods[k]["precision"].as_f64().unwrap();
    assert!(precision(1) > precision(3) + 0.05, "shi-tomasi {} vs random {}", precision(1), precision(3));

    let p = p.to_str().unwrap();
    a_coco_file_of_the_same_photos_gives_the_same_report(dir.path(), c, i, p, &report);
    a_label_off_the_photo_is_named(dir.path(), c, i, p);
    no_photo_and_a_bad_radius_are_refused(dir.path(), c, i, p);
}

/// The same photos named by a COCO file (as `coco-from-points` writes its
/// halves; paths relative to the file): the same report.
fn a_coco_file_of_the_same_photos_gives_the_same_report(
    dir: &std::path::Path,
    c: &str,
    i: &str,
    p: &str,
    report: &serde_json::Value,
) {
    let coco = serde_json::json!({
        "images": [
            {"id": 1, "file_name": "images/P1020826.jpg", "width": 640, "height": 480},
            {"id": 2, "file_name": "images/P1020830.jpg", "width": 640, "height": 480},
        ],
        "annotations": [],
        "categories": [{"id": 1, "name": "corner"}],
    });
    let coco_path = dir.join("test.json");
    std::fs::write(&coco_path, coco.to_string()).unwrap();
    let cp = coco_path.to_str().unwrap();
    let out = infer(&["eval-points", "--checkpoint", c, "--images", cp, "--points", p, "--json"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert_eq!(serde_json::from_slice::<serde_json::Value>(&out.stdout).unwrap(), *report);
    // A COCO image without a points file is named.
    let out = infer(&["eval-points", "--checkpoint", c, "--images", cp, "--points", i]);
    let message = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && message.contains("P1020826.csv"), "{message}");
}

/// A label off the photo (another image's, or another size's) is named,
/// not counted as a miss.
fn a_label_off_the_photo_is_named(dir: &std::path::Path, c: &str, i: &str, p: &str) {
    let p = std::path::Path::new(p);
    let shifted = dir.join("shifted");
    std::fs::create_dir(&shifted).unwrap();
    for name in ["P1020826", "P1020830"] {
        std::fs::copy(p.join(format!("{name}.csv")), shifted.join(format!("{name}.csv"))).unwrap();
    }
    let text = std::fs::read_to_string(shifted.join("P1020830.csv")).unwrap();
    std::fs::write(shifted.join("P1020830.csv"), format!("{}700.5,20\n", text)).unwrap();
    let out = infer(&["eval-points", "--checkpoint", c, "--images", i, "--points", shifted.to_str().unwrap()]);
    let message = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success()
            && message.contains("P1020830.csv")
            && message.contains("(700.5, 20) lies outside the 640x480"),
        "{message}"
    );
}

/// No labelled photo, a bad radius: named refusals.
fn no_photo_and_a_bad_radius_are_refused(dir: &std::path::Path, c: &str, i: &str, p: &str) {
    let empty = dir.join("empty");
    std::fs::create_dir(&empty).unwrap();
    let out = infer(&["eval-points", "--checkpoint", c, "--images", empty.to_str().unwrap(), "--points", p]);
    let message = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && message.contains("no photograph in") && message.contains("empty"), "{message}");
    let out = infer(&["eval-points", "--checkpoint", c, "--images", i, "--points", p, "--radius", "-1"]);
    assert!(!out.status.success() && String::from_utf8_lossy(&out.stderr).contains("--radius"));
}
