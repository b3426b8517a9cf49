//! The `localize` command's JSON outputs and its errors.

use std::process::Command;

/// The package folder, read when the test runs (cargo sets it), so that a
/// test binary reused from another checkout still finds its files.
fn manifest_dir() -> std::path::PathBuf {
    std::env::var_os("CARGO_MANIFEST_DIR").map_or_else(|| env!("CARGO_MANIFEST_DIR").into(), Into::into)
}

fn localize(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_localize")).args(args).output().expect("runs")
}

fn shared(path: &str) -> String {
    format!("{}/../../shared/data/{path}", manifest_dir().display())
}

#[test]
fn eval_json_has_the_documented_keys_and_evo_numbers() {
    let gt = shared("evo_trajectories/freiburg1_xyz-groundtruth.txt");
    let est = shared("evo_trajectories/freiburg1_xyz-rgbdslam.txt");
    let out = localize(&["eval", "--gt", &gt, "--est", &est, "--align", "se3", "--json"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["matched"], 785);
    for (key, want) in [("rmse_x", 0.010005), ("rmse_y", 0.007606), ("rmse_z", 0.004847), ("ate_rmse", 0.013470)] {
        let got = v[key].as_f64().unwrap_or_else(|| panic!("no {key}"));
        assert!((got - want).abs() < 1e-4, "{key}: {got} vs {want}");
    }
}

#[test]
fn planes_json_gives_the_rooms_floor_ceiling_and_walls() {
    let out = localize(&["planes", "--json", &shared("pcl_room_scans/room_scan1.pcd")]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let planes: Vec<([f64; 3], f64, u64)> = v["planes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| {
            let n: Vec<f64> = p["normal"].as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect();
            ([n[0], n[1], n[2]], p["distance"].as_f64().unwrap(), p["inliers"].as_u64().unwrap())
        })
        .collect();
    for (n, d, inliers) in &planes {
        assert!(((n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt() - 1.0).abs() < 1e-9);
        assert!(*d >= 0.0 && *inliers > 0);
    }
    // The data's README: floor at z = -1.27 m, ceiling at +1.68 m (as the
    // library's geometry test finds them), the room 4.5 m wide along y.
    let horizontal = |d: f64| planes.iter().any(|(n, dist, _)| n[2].abs() > 0.999 && (dist - d).abs() < 0.05);
    assert!(horizontal(1.27) && horizontal(1.66), "{planes:?}");
    let wall = |sign: f64| {
        planes.iter().find(|(n, _, inliers)| n[1] * sign > 0.99 && *inliers > 1000).map(|p| p.1).expect("a wall")
    };
    assert!((wall(1.0) + wall(-1.0) - 4.5).abs() < 0.1, "{planes:?}");
    // Each corner names three distinct planes of the list and lies on all three.
    let corners = v["corners"].as_array().unwrap();
    assert!(!corners.is_empty());
    for c in corners {
        let ids: Vec<usize> = c["planes"].as_array().unwrap().iter().map(|i| i.as_u64().unwrap() as usize).collect();
        assert!(ids.len() == 3 && ids[0] != ids[1] && ids[1] != ids[2] && ids[0] != ids[2], "{c}");
        let p: Vec<f64> = c["position"].as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect();
        for &i in &ids {
            let (n, d, _) = planes[i];
            let off = n[0] * p[0] + n[1] * p[1] + n[2] * p[2] - d;
            assert!(off.abs() < 1e-6, "corner {c} is {off} m off plane {i}");
        }
    }
}

#[test]
fn bad_input_gives_a_message_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let cloud = dir.path().join("nan.pcd");
    std::fs::write(&cloud, "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 2\nHEIGHT 1\nPOINTS 2\nDATA ascii\nnan nan nan\nnan 0 0\n").unwrap();
    let out = localize(&["planes", cloud.to_str().unwrap()]);
    assert!(!out.status.success());
    let message = String::from_utf8_lossy(&out.stderr);
    assert!(message.contains("nan.pcd") && message.contains("no finite points"), "{message}");
    let missing = dir.path().join("missing.txt");
    let out = localize(&["eval", "--gt", missing.to_str().unwrap(), "--est", missing.to_str().unwrap()]);
    assert!(String::from_utf8_lossy(&out.stderr).contains("missing.txt"));
    // An output that cannot be written is refused before the recording is read.
    let blocker = dir.path().join("a-file");
    std::fs::write(&blocker, "x").unwrap();
    let unwritable = blocker.join("runs").join("r1");
    let out = localize(&["run", "--sequence", "no-such-folder", "--out", unwritable.to_str().unwrap()]);
    let m = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && m.contains("a-file") && !m.contains("no-such-folder"), "{m}");
    // A start in a map needs the map, and four numbers.
    let out = localize(&["run", "--sequence", "s", "--out", "o", "--start-pose", "1,2,0,90"]);
    assert!(!out.status.success() && String::from_utf8_lossy(&out.stderr).contains("--map"));
    let out = localize(&["run", "--sequence", "s", "--out", "o", "--map", "m", "--start-pose", "1,2,x"]);
    let m = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && m.contains("--start-pose") && m.contains("`x` is not a number"), "{m}");
    let out = localize(&["run", "--sequence", "s", "--out", "o", "--map", "m", "--start-pose", "1,2,0"]);
    let m = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && m.contains("X,Y,Z,YAW_DEG"), "{m}");
    let out = localize(&["eval", "--gt", "a", "--est", "b", "--align", "affine"]);
    assert!(!out.status.success() && String::from_utf8_lossy(&out.stderr).contains("affine"));
    // Ground truth with a repeated stamp (another pose) or out of order: an
    // error naming the file and the pose, not an ATE from wrong pairs.
    let good = dir.path().join("good.txt");
    std::fs::write(&good, "0 0 0 0 0 0 0 1\n1 1 0 0 0 0 0 1\n2 2 0 0 0 0 0 1\n").unwrap();
    for (name, text, expected) in [
        ("dup.txt", "0 0 0 0 0 0 0 1\n1 1 0 0 0 0 0 1\n1 5 0 0 0 0 0 1\n2 2 0 0 0 0 0 1\n", "duplicate timestamp"),
        ("unsorted.txt", "0 0 0 0 0 0 0 1\n2 2 0 0 0 0 0 1\n1 1 0 0 0 0 0 1\n", "decreasing timestamp"),
    ] {
        let gt = dir.path().join(name);
        std::fs::write(&gt, text).unwrap();
        let out = localize(&["eval", "--gt", gt.to_str().unwrap(), "--est", good.to_str().unwrap()]);
        let m = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && m.contains(name) && m.contains(expected), "{m}");
    }
}

#[test]
fn a_real_tum_ground_truth_with_a_stamp_written_twice_scores_as_evo_scores_it() {
    // fr2_desk's motion capture has 1311868229.5760 twice, 1.2 mm and 0.6 degrees apart.
    let gt = shared("evo_trajectories/fr2_desk_groundtruth.txt");
    let est = shared("evo_trajectories/fr2_desk_ORB.txt");
    let out = localize(&["eval", "--gt", &gt, "--est", &est, "--align", "se3", "--json"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(err.contains("fr2_desk_groundtruth.txt: 1 time stamp(s) written twice"), "{err}");
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let ate = json["ate_rmse"].as_f64().unwrap();
    // evo_ape tum fr2_desk_groundtruth.txt fr2_desk_ORB.txt -a: rmse 0.008119.
    assert!((ate - 0.0081190).abs() < 1e-6, "{json}");
}

fn recording(name: &str) -> String {
    format!("{}/../datasets/tests/data/recordings/{name}", manifest_dir().display())
}

#[test]
fn inspect_prints_topics_counts_rates_and_roles() {
    let out = localize(&["inspect", &recording("ros1_lz4.bag")]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8_lossy(&out.stdout);
    for want in ["ROS 1 bag", "Messages:          331", "/imu", "sensor_msgs/msg/Imu", "200 msgs", "ros1", "Duration:"]
    {
        assert!(text.contains(want), "no `{want}` in\n{text}");
    }
    assert!(text.contains("lidar        /points (sensor_msgs/msg/PointCloud2, 10 messages)"), "{text}");
    assert!(text.contains("camera       /camera/image_raw (sensor_msgs/msg/Image, 30 messages)"), "{text}");
    assert!(text.contains("ground truth /ground_truth"), "{text}");
    // A recording that cannot be run says why, and still prints what it holds.
    let out = localize(&["inspect", &shared("ros_recordings/nav2_turtlebot.mcap")]);
    assert!(out.status.success());
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        text.contains("/amcl_pose")
            && text.contains("2639 msgs")
            && text.contains("no sensor_msgs/msg/PointCloud2 topic"),
        "{text}"
    );
}

#[test]
fn run_on_a_bag_writes_the_trajectory_in_the_recording_clock_and_its_metrics() {
    let dir = tempfile::tempdir().unwrap();
    let out_dir = dir.path().join("run");
    let checkpoint = manifest_dir().join("../checkpoints/alexnet");
    let bag = recording("rosbag2_mcap");
    let run = |out: &std::path::Path, extra: &[&str]| {
        let mut args = vec!["run", "--bag", &bag, "--checkpoint", checkpoint.to_str().unwrap()];
        args.extend(["--out", out.to_str().unwrap()]);
        args.extend(extra);
        localize(&args)
    };
    let out = run(&out_dir, &[]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("10 of 10 scans have an image within 0.05 s"), "{stdout}");
    let (trajectory, _) = datasets::io::formats::read_trajectory(&out_dir.join("trajectory.txt")).unwrap();
    assert_eq!(trajectory.len(), 10);
    // Epoch seconds of the LIDAR's header stamps.
    for (k, t) in trajectory.stamps.iter().enumerate() {
        assert!((t - (1_700_000_000.0 + 0.1 * k as f64)).abs() < 1e-6, "{t}");
    }
    let metrics: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out_dir.join("metrics.json")).unwrap()).unwrap();
    assert_eq!(metrics["frames"], 10);
    assert_eq!(metrics["fused"]["overall"]["matched"], 10);
    // The terminal's table says what metrics.json says.
    let ate = metrics["fused"]["overall"]["ate_rmse"].as_f64().unwrap();
    let row = stdout.lines().find(|l| l.starts_with("fused all")).unwrap_or_else(|| panic!("{stdout}"));
    let printed: f64 = row.split_whitespace().last().unwrap().parse().unwrap();
    assert!((printed - ate).abs() < 5e-5, "{row} vs {ate}");
    assert!(stdout.lines().any(|l| l.starts_with("odometry/IMU all")), "{stdout}");
    // Simulated faults count from the first scan, whatever the recording's clock.
    let faulty = dir.path().join("faulty");
    let out = run(&faulty, &["--lidar-gap", "0.25:0.55"]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(stderr.contains("no scan for 0.40 s before the scan at 1700000000.600"), "{stderr}");
    let frames = std::fs::read_to_string(faulty.join("frames.csv")).unwrap();
    assert_eq!(frames.lines().count(), 1 + 7, "{frames}");
    assert!(frames.lines().any(|l| l.starts_with("1700000000.600000,0.400,")), "{frames}");
    let refused = run(std::path::Path::new("x"), &["--lidar-gap", "5:3"]);
    let message = String::from_utf8_lossy(&refused.stderr);
    assert!(
        !refused.status.success() && message.contains("--lidar-gap") && message.contains("after START"),
        "{message}"
    );
}

#[test]
fn bad_recordings_get_errors_naming_the_topic_and_message() {
    let dir = tempfile::tempdir().unwrap();
    let bytes = std::fs::read(recording("ros1_plain.bag")).unwrap();
    let run = |bag: &std::path::Path| {
        let out = localize(&["run", "--bag", bag.to_str().unwrap(), "--out", dir.path().join("o").to_str().unwrap()]);
        assert!(!out.status.success());
        String::from_utf8_lossy(&out.stderr).to_string()
    };
    // The scan at +0.5 s stamped +0.1 s: the LIDAR's clock jumps back.
    let mut jumped = bytes.clone();
    let mut pattern = 1_700_000_000u32.to_le_bytes().to_vec();
    pattern.extend_from_slice(&500_000_000u32.to_le_bytes());
    pattern.extend_from_slice(&10u32.to_le_bytes());
    pattern.extend_from_slice(b"lidar_link");
    let at = jumped.windows(pattern.len()).position(|w| w == pattern.as_slice()).expect("scan 5's header");
    jumped[at + 4..at + 8].copy_from_slice(&100_000_000u32.to_le_bytes());
    let path = dir.path().join("jumped.bag");
    std::fs::write(&path, &jumped).unwrap();
    let e = run(&path);
    assert!(e.contains("topic /points, message 5: the clock jumps back"), "{e}");
    // No /tf_static (renamed in place) and no --calib.
    let mut no_tf = bytes.clone();
    while let Some(at) = no_tf.windows(10).position(|w| w == b"/tf_static") {
        no_tf[at..at + 10].copy_from_slice(b"/tf_statix");
    }
    let path = dir.path().join("no_tf.bag");
    std::fs::write(&path, &no_tf).unwrap();
    let e = run(&path);
    assert!(e.contains("no /tf_static topic and no --calib"), "{e}");
    // A recording that is not there.
    let path = recording("rosbag2_sqlite3");
    let e = run(std::path::Path::new(&path).join("missing").as_path());
    assert!(e.contains("missing") && e.contains("no such file or folder"), "{e}");
}

#[test]
fn eval_takes_a_pose_topic_of_a_bag_as_evo_does() {
    let bag = shared("ros_recordings/ROS_example.bag");
    let gt_tum = shared("ros_recordings/evo_reference/groundtruth.tum");
    let est_tum = shared("ros_recordings/evo_reference/S-PTAM.tum");
    let from_files =
        localize(&["eval", "--gt", &gt_tum, "--est", &est_tum, "--align", "se3", "--max-diff", "0.05", "--json"]);
    let from_bag = localize(&[
        "eval",
        "--gt",
        &bag,
        "--gt-topic",
        "groundtruth",
        "--est",
        &bag,
        "--est-topic",
        "S-PTAM",
        "--align",
        "se3",
        "--max-diff",
        "0.05",
        "--json",
    ]);
    assert!(from_bag.status.success(), "{}", String::from_utf8_lossy(&from_bag.stderr));
    let a: serde_json::Value = serde_json::from_slice(&from_files.stdout).unwrap();
    let b: serde_json::Value = serde_json::from_slice(&from_bag.stdout).unwrap();
    assert!(a["matched"].as_u64().unwrap() > 1000);
    assert_eq!(a["matched"], b["matched"]);
    let (x, y) = (a["ate_rmse"].as_f64().unwrap(), b["ate_rmse"].as_f64().unwrap());
    assert!((x - y).abs() < 1e-9, "{x} vs {y}");
    let out = localize(&["eval", "--gt", &bag, "--est", &est_tum]);
    assert!(String::from_utf8_lossy(&out.stderr).contains("name its pose topic with --gt-topic"));
}

#[test]
fn absurd_settings_in_a_config_file_are_named_before_anything_runs() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("settings.json");
    std::fs::write(&config, r#"{"normals": {"neighbours": 100000}}"#).unwrap();
    let out = localize(&[
        "run",
        "--sequence",
        dir.path().to_str().unwrap(),
        "--config",
        config.to_str().unwrap(),
        "--out",
        dir.path().join("out").to_str().unwrap(),
    ]);
    let message = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success()
            && message.contains("settings.json")
            && message.contains("normals.neighbours: 100000 outside"),
        "{message}"
    );
    assert!(!dir.path().join("out").exists());
}

#[test]
fn a_used_output_folder_is_replaced_whole_and_a_foreign_one_refused() {
    let dir = tempfile::tempdir().unwrap();
    let out_dir = dir.path().join("run");
    std::fs::create_dir_all(&out_dir).unwrap();
    // An earlier run's files and a temporary file a killed writer left.
    std::fs::write(out_dir.join("frames.csv"), "stale").unwrap();
    std::fs::write(out_dir.join(".tmp-x1"), "partial").unwrap();
    let checkpoint = manifest_dir().join("../checkpoints/alexnet");
    let bag = recording("rosbag2_mcap");
    let run = |out: &std::path::Path| {
        localize(&["run", "--bag", &bag, "--checkpoint", checkpoint.to_str().unwrap(), "--out", out.to_str().unwrap()])
    };
    let out = run(&out_dir);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let frames = std::fs::read_to_string(out_dir.join("frames.csv")).unwrap();
    assert!(frames.lines().count() == 11, "{frames}");
    assert!(!out_dir.join(".tmp-x1").exists());
    let names: Vec<String> =
        std::fs::read_dir(&out_dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    assert!(names.iter().all(|n| localize::run::RUN_OUTPUTS.contains(&n.as_str())), "{names:?}");
    // A folder with somebody else's file is refused before any work, untouched.
    let foreign = dir.path().join("mine");
    std::fs::create_dir_all(&foreign).unwrap();
    std::fs::write(foreign.join("notes.txt"), "keep").unwrap();
    let out = run(&foreign);
    let message = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && message.contains("notes.txt") && message.contains("mine"), "{message}");
    assert_eq!(std::fs::read_to_string(foreign.join("notes.txt")).unwrap(), "keep");
    assert_eq!(std::fs::read_dir(&foreign).unwrap().count(), 1);
}

#[test]
fn an_error_prints_each_cause_once_without_a_backtrace() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("missing.txt");
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_localize"))
        .args(["eval", "--gt", missing.to_str().unwrap(), "--est", missing.to_str().unwrap()])
        .env("RUST_BACKTRACE", "1")
        .output()
        .unwrap();
    let message = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && message.contains("missing.txt"), "{message}");
    assert_eq!(message.matches("No such file").count(), 1, "{message}");
    assert!(!message.to_lowercase().contains("backtrace"), "{message}");
    let out = localize(&["bench", "--frames", "-1"]);
    let message = String::from_utf8_lossy(&out.stderr);
    assert!(message.contains("--frames") && message.contains("at least 1, got -1"), "{message}");
}

#[test]
fn autolabel_refuses_bad_settings_and_a_foreign_folder_before_any_work() {
    let dir = tempfile::tempdir().unwrap();
    let settings = dir.path().join("bad.json");
    std::fs::write(&settings, r#"{"tracks": {"gate_m": -1}}"#).unwrap();
    let out_dir = dir.path().join("labels");
    let missing = dir.path().join("no-such-sequence");
    let run = |args: &[&str]| {
        let out = localize(args);
        assert!(!out.status.success());
        String::from_utf8_lossy(&out.stderr).into_owned()
    };
    let (s, m, o) = (settings.to_str().unwrap(), missing.to_str().unwrap(), out_dir.to_str().unwrap());
    let e = run(&["autolabel", "--sequence", m, "--out", o, "--autolabel-config", s]);
    assert!(e.contains("bad.json") && e.contains("tracks.gate_m"), "{e}");
    let e = run(&["autolabel", "--sequence", m, "--out", o]);
    assert!(e.contains("no-such-sequence"), "{e}");
    std::fs::create_dir_all(&out_dir).unwrap();
    std::fs::write(out_dir.join("mine.txt"), "not a label").unwrap();
    let e = run(&["autolabel", "--sequence", m, "--out", o]);
    assert!(e.contains("labels") && e.contains("earlier autolabel"), "{e}");
    assert!(out_dir.join("mine.txt").is_file());
}
