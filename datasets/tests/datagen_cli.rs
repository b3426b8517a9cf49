//! The `datagen` command's handling of bad flags and settings files: a clear
//! message naming the problem, a non-zero exit, and nothing written.

use std::process::Command;

fn datagen(args: &[&str]) -> (bool, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_datagen")).args(args).output().unwrap();
    (out.status.success(), String::from_utf8_lossy(&out.stderr).into_owned())
}

#[test]
fn bad_flags_and_settings_are_named() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let o = out.to_str().unwrap();

    let (ok, err) = datagen(&["--out", o, "--speed", "-1"]);
    assert!(!ok && err.contains("sequence.speed_mps: -1 m/s"), "{err}");
    let (ok, err) = datagen(&["--out", o, "--speed", "fast"]);
    assert!(!ok && err.contains("--speed") && err.contains("fast"), "{err}");
    let (ok, err) = datagen(&["--out", o, "--images", "10", "--train", "20"]);
    assert!(!ok && err.contains("detection.train: 20 is larger than the 10 images"), "{err}");
    for frames in ["0", "-1"] {
        let (ok, err) = datagen(&["--out", o, "--frames", frames]);
        assert!(!ok && err.contains("--frames") && err.contains("at least 1"), "{err}");
    }
    // Sizes that would fill the disk are refused before anything is written.
    let (ok, err) = datagen(&["--out", o, "--frames", "99999999999"]);
    assert!(!ok && err.contains("sequence.frames: 99999999999 outside 1..=100000"), "{err}");
    let (ok, err) = datagen(&["--out", o, "--images", "99999999999", "--train", "1"]);
    assert!(!ok && err.contains("detection.images: 99999999999 outside 0..=100000"), "{err}");
    // A corridor of no length is not the paper's building.
    let (ok, err) = datagen(&["--out", o, "--corridor", "0"]);
    assert!(!ok && err.contains("--corridor") && err.contains("above 0"), "{err}");
    let (ok, err) = datagen(&["--out", o, "--building", "2000000"]);
    assert!(!ok && err.contains("world.building: 2000000 outside"), "{err}");
    let (ok, err) = datagen(&["--out", o, "--building", "-3"]);
    assert!(!ok && err.contains("--building"), "{err}");
    let (ok, err) = datagen(&["--out", o, "--start-m", "-2"]);
    assert!(!ok && err.contains("sequence.start_m: -2 m"), "{err}");
    let (ok, err) = datagen(&["--out", o, "--start-m", "5000", "--images", "0", "--train", "0"]);
    assert!(!ok && err.contains("past the end of the") && err.contains("route"), "{err}");
    let (ok, err) = datagen(&["--out", o, "--colour", "red"]);
    assert!(!ok && err.contains("--colour"), "{err}");
    assert!(!out.exists(), "nothing is written for a bad command line");

    let settings = dir.path().join("settings.json");
    std::fs::write(&settings, r#"{"world": {"ramp_slope_deg": 45}}"#).unwrap();
    let (ok, err) = datagen(&["--out", o, "--config", settings.to_str().unwrap()]);
    assert!(!ok && err.contains("settings.json") && err.contains("world.ramp_slope_deg: 45 deg"), "{err}");
    std::fs::write(&settings, r#"{"wrld": {}}"#).unwrap();
    let (ok, err) = datagen(&["--out", o, "--config", settings.to_str().unwrap()]);
    assert!(!ok && err.contains("settings.json") && err.contains("wrld"), "{err}");
    let (ok, err) = datagen(&["--out", o, "--config", "/nonexistent/settings.json"]);
    assert!(!ok && err.contains("/nonexistent/settings.json"), "{err}");

    let file = dir.path().join("a_file");
    std::fs::write(&file, "x").unwrap();
    let (ok, err) = datagen(&["--out", file.to_str().unwrap()]);
    assert!(!ok && err.contains("is not a folder"), "{err}");
}

#[test]
fn a_tiny_run_writes_the_documented_layout() {
    let dir = tempfile::tempdir().unwrap();
    let o = dir.path().to_str().unwrap();
    let bag = dir.path().join("sequence.mcap");
    let (ok, err) = datagen(&[
        "--out",
        o,
        "--images",
        "3",
        "--train",
        "2",
        "--frames",
        "2",
        "--speed",
        "0.5",
        "--rate",
        "2",
        "--seed",
        "11",
        "--bag",
        bag.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    for rel in [
        "datagen.json",
        "detection/train.json",
        "detection/test.json",
        "detection/images/000002.png",
        "detection/canny/000002.png",
        "sequence/rgb/0000000000.500000.png",
        "sequence/cloud/0000000000.500000.pcd",
        "sequence/odom.csv",
        "sequence/imu.csv",
        "sequence/groundtruth.txt",
        "sequence/calib.json",
        "sequence/labels.json",
        "sequence/world.json",
        "preview/topdown.png",
    ] {
        assert!(dir.path().join(rel).is_file(), "{rel} is missing");
    }
    let settings: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("datagen.json")).unwrap()).unwrap();
    assert_eq!(settings["seed"], 11);
    assert_eq!(settings["sequence"]["rate_hz"], 2.0);
    // The same sequence as a ROS 2 recording.
    let recording = datasets::io::recording::Recording::open(&bag).unwrap();
    let count = |topic: &str| recording.topics[recording.topic(topic).unwrap()].count;
    assert_eq!(
        [count("/points"), count("/camera/image_raw/compressed"), count("/ground_truth"), count("/tf_static")],
        [2, 2, 2, 1]
    );
    let imu_rows = std::fs::read_to_string(dir.path().join("sequence/imu.csv")).unwrap().lines().count() as u64 - 1;
    assert_eq!(count("/imu"), imu_rows);

    // A shorter run into the same folder leaves none of the longer run's
    // frames or images behind; files that are not a run's stay.
    std::fs::write(dir.path().join("notes.txt"), "mine").unwrap();
    let (ok, err) = datagen(&["--out", o, "--images", "1", "--train", "1", "--frames", "1", "--seed", "11"]);
    assert!(ok, "{err}");
    let count_in = |rel: &str| std::fs::read_dir(dir.path().join(rel)).unwrap().count();
    assert_eq!((count_in("sequence/cloud"), count_in("sequence/rgb"), count_in("detection/images")), (1, 1, 1));
    assert!(dir.path().join("notes.txt").is_file() && dir.path().join("datagen.json").is_file());
}
