//! `coco-from-points`: photographs with point labels become a detection
//! data set (`train.json`, `test.json`) that names the photos where they
//! are; bad flags and folders are refused before anything is written.

use std::path::Path;
use std::process::Command;

use datasets::io::formats::read_coco;

fn coco_from_points(args: &[&str]) -> (bool, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_coco-from-points")).args(args).output().unwrap();
    (out.status.success(), String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr))
}

/// Five 64 x 48 photos `p0`..`p4` (p4 without labels), with labels in
/// MATLAB's convention: one in the middle, one at the corner pixel, one
/// outside the photo.
fn photos(dir: &Path) -> (String, String) {
    let (images, points) = (dir.join("images"), dir.join("points"));
    std::fs::create_dir_all(&images).unwrap();
    std::fs::create_dir_all(&points).unwrap();
    for k in 0..5 {
        image::GrayImage::new(64, 48).save(images.join(format!("p{k}.png"))).unwrap();
        if k < 4 {
            std::fs::write(points.join(format!("p{k}.csv")), "x,y,type\n32.5,24.5,L\n1,1,T\n70,10,L\n").unwrap();
        }
    }
    (images.to_str().unwrap().to_string(), points.to_str().unwrap().to_string())
}

#[test]
fn photos_and_points_become_train_and_test_halves() {
    let dir = tempfile::tempdir().unwrap();
    let (images, points) = photos(dir.path());
    let out = dir.path().join("coco");
    let o = out.to_str().unwrap();
    let (ok, log) = coco_from_points(&["--images", &images, "--points", &points, "--out", o, "--box-size", "16"]);
    assert!(ok, "{log}");
    assert!(log.contains("train.json: 2 photos, 4 points; test.json: 2 photos, 4 points"), "{log}");
    assert!(log.contains("4 points outside their photo left out"), "{log}");
    let (train, test) = (read_coco(&out.join("train.json")).unwrap(), read_coco(&out.join("test.json")).unwrap());
    let names = |set: &datasets::io::formats::CocoDataset| -> Vec<String> {
        set.images
            .iter()
            .map(|im| Path::new(&im.file_name).file_name().unwrap().to_string_lossy().into_owned())
            .collect()
    };
    // Sorted by name, every second photo to the test half.
    assert_eq!(names(&train), ["p0.png", "p2.png"]);
    assert_eq!(names(&test), ["p1.png", "p3.png"]);
    assert!(test.images.iter().all(|im| Path::new(&im.file_name).is_absolute() && (im.width, im.height) == (64, 48)));
    // The middle point: a 16 px box around pixel (31.5, 23.5)'s centre.
    let middle = &train.annotations[0];
    assert_eq!((middle.point, middle.bbox), (Some([32.0, 24.0]), [24.0, 16.0, 16.0, 16.0]));
    assert_eq!(middle.corner_type.as_deref(), Some("L"));
    // The corner pixel's box is clipped to the photo.
    let corner = &train.annotations[1];
    assert_eq!((corner.point, corner.bbox), (Some([0.5, 0.5]), [0.0, 0.0, 8.5, 8.5]));
    assert_eq!(corner.corner_type.as_deref(), Some("T"));
    let ids: Vec<u64> = train.annotations.iter().chain(&test.annotations).map(|a| a.id).collect();
    assert_eq!(ids.len(), ids.iter().collect::<std::collections::HashSet<_>>().len(), "annotation ids are unique");

    let (ok, log) = coco_from_points(&["--images", &images, "--points", &points, "--out", o, "--test-every", "4"]);
    assert!(ok && log.contains("train.json: 3 photos") && log.contains("test.json: 1 photos"), "{log}");
}

#[test]
fn bad_flags_and_folders_are_named_and_nothing_is_written() {
    let dir = tempfile::tempdir().unwrap();
    let (images, points) = photos(dir.path());
    let out = dir.path().join("coco");
    let o = out.to_str().unwrap();
    let (ok, err) = coco_from_points(&["--images", &images, "--points", &points, "--out", o, "--test-every", "1"]);
    assert!(!ok && err.contains("--test-every"), "{err}");
    let (ok, err) = coco_from_points(&["--images", &images, "--points", &points, "--out", o, "--box-size", "1000"]);
    assert!(!ok && err.contains("--box-size 1000"), "{err}");
    let (ok, err) = coco_from_points(&["--images", &points, "--points", &points, "--out", o]);
    assert!(!ok && err.contains("no photograph in this folder"), "{err}");
    let missing = dir.path().join("missing");
    let (ok, err) = coco_from_points(&["--images", missing.to_str().unwrap(), "--points", &points, "--out", o]);
    assert!(!ok && err.contains("missing"), "{err}");
    let (ok, err) = coco_from_points(&["--images", &images, "--points", &points, "--out", o, "--test-every", "9"]);
    assert!(!ok && err.contains("4 labelled photos, too few"), "{err}");
    std::fs::write(Path::new(&points).join("p2.csv"), "x,y\n3,oops\n").unwrap();
    let (ok, err) = coco_from_points(&["--images", &images, "--points", &points, "--out", o]);
    assert!(!ok && err.contains("p2.csv") && err.contains("line 2"), "{err}");
    assert!(!out.exists(), "nothing is written for a refused command");
}
