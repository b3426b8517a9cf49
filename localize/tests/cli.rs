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
fn planes_json_gives_unit_normals_and_nonnegative_distances() {
    let out = localize(&["planes", "--json", &shared("pcl_room_scans/room_scan2.pcd")]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let planes = v["planes"].as_array().unwrap();
    assert!(planes.len() >= 4);
    for p in planes {
        let n: Vec<f64> = p["normal"].as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect();
        assert!(((n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt() - 1.0).abs() < 1e-9);
        assert!(p["distance"].as_f64().unwrap() >= 0.0);
        assert!(p["inliers"].as_u64().unwrap() > 0);
    }
    assert!(v["corners"].as_array().unwrap().iter().all(|c| c["position"].as_array().unwrap().len() == 3));
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
    let out = localize(&["eval", "--gt", "a", "--est", "b", "--align", "affine"]);
    assert!(!out.status.success() && String::from_utf8_lossy(&out.stderr).contains("affine"));
}
