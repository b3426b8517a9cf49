//! Trajectory metrics against hand-computed values and evo 1.38.1's numbers
//! on real trajectories (`evo_reference_results.txt` in the shared data).

use std::path::PathBuf;

use datasets::io::formats::{Trajectory, read_trajectory};
use datasets::math::{Pose3, Vec3};
use localize::evaluation::eval::{Alignment, associate, compare};
use localize::evaluation::similarity::umeyama;
use nalgebra::{Translation3, UnitQuaternion};

/// The package folder, read when the test runs (cargo sets it), so that a
/// test binary reused from another checkout still finds its files.
fn manifest_dir() -> std::path::PathBuf {
    std::env::var_os("CARGO_MANIFEST_DIR").map_or_else(|| env!("CARGO_MANIFEST_DIR").into(), Into::into)
}

fn evo(name: &str) -> PathBuf {
    manifest_dir().join("../../shared/data/evo_trajectories").join(name)
}

fn load(name: &str) -> Trajectory {
    read_trajectory(&evo(name)).unwrap_or_else(|e| panic!("{e} (the shared data folder is needed for this test)")).0
}

fn at(x: f64, y: f64, z: f64) -> Pose3 {
    Pose3::from_parts(Translation3::new(x, y, z), UnitQuaternion::identity())
}

#[test]
fn rmse_of_a_hand_computed_example() {
    let mut gt = Trajectory::default();
    gt.push(0.0, at(0.0, 0.0, 0.0));
    gt.push(1.0, at(1.0, 0.0, 0.0));
    let mut est = Trajectory::default();
    est.push(0.004, at(0.1, 0.0, 0.0));
    est.push(1.0, at(1.0, 0.2, -0.3));
    est.push(7.0, at(9.0, 9.0, 9.0)); // no partner: left out
    let c = compare(&gt, &est, Alignment::None, 0.01).unwrap();
    let s = c.summary;
    assert_eq!(s.matched, 2);
    assert!((s.rmse_x - (0.01f64 / 2.0).sqrt()).abs() < 1e-12);
    assert!((s.rmse_y - (0.04f64 / 2.0).sqrt()).abs() < 1e-12);
    assert!((s.rmse_z - (0.09f64 / 2.0).sqrt()).abs() < 1e-12);
    assert!((s.ate_rmse - ((0.01 + 0.04 + 0.09) / 2.0f64).sqrt()).abs() < 1e-12);
    // Outside the time window nothing matches.
    assert!(compare(&gt, &est, Alignment::None, 0.001).unwrap().summary.matched == 1);
}

#[test]
fn umeyama_recovers_a_known_similarity() {
    let rotation = UnitQuaternion::from_euler_angles(0.3, -0.2, 1.1);
    let t = Vec3::new(1.5, -2.0, 0.7);
    let from: Vec<Vec3> =
        (0..20).map(|k| Vec3::new((k as f64).sin() * 3.0, (k as f64 * 0.7).cos(), k as f64 * 0.1)).collect();
    let to: Vec<Vec3> = from.iter().map(|p| 2.5 * (rotation * p) + t).collect();
    let s = umeyama(&from, &to, true).unwrap();
    assert!((s.scale - 2.5).abs() < 1e-9);
    assert!((s.rotation - rotation.to_rotation_matrix().into_inner()).abs().max() < 1e-9);
    assert!((s.translation - t).norm() < 1e-9);
    let rigid: Vec<Vec3> = from.iter().map(|p| rotation * p + t).collect();
    let s = umeyama(&from, &rigid, false).unwrap();
    assert!((s.scale - 1.0).abs() < 1e-15 && (s.translation - t).norm() < 1e-9);
    assert!(umeyama(&from[..2], &rigid[..2], false).is_none());
}

#[test]
fn association_matches_evo_pairs_nearest_first() {
    let mut a = Trajectory::default();
    let mut b = Trajectory::default();
    for (k, t) in [0.0, 1.0, 2.0, 3.0].iter().enumerate() {
        a.push(*t, at(k as f64, 0.0, 0.0));
    }
    for t in [0.005, 0.995, 1.005, 2.5] {
        b.push(t, at(t, 0.0, 0.0));
    }
    // b is not longer: each pose of b takes its nearest in a.
    let pairs = associate(&a, &b, 0.01).pairs;
    assert_eq!(pairs, vec![(0, 0), (1, 1), (1, 2)]);
}

fn check(c: &localize::evaluation::eval::ErrorSummary, rmse: f64, mean: f64, median: f64, max: f64) {
    for (got, want) in [(c.ate_rmse, rmse), (c.ate_mean, mean), (c.ate_median, median), (c.ate_max, max)] {
        assert!((got - want).abs() < 1e-4 * 0.5 + 1e-6, "{got} vs evo {want}");
    }
}

#[test]
fn agrees_with_evo_ape_on_tum_rgbd() {
    let gt = load("freiburg1_xyz-groundtruth.txt");
    let est = load("freiburg1_xyz-rgbdslam.txt");
    let raw = compare(&gt, &est, Alignment::None, 0.01).unwrap().summary;
    assert_eq!(raw.matched, 785);
    check(&raw, 0.020079, 0.018063, 0.016518, 0.043289);
    for (got, want) in [(raw.rmse_x, 0.017381), (raw.rmse_y, 0.006598), (raw.rmse_z, 0.007586)] {
        assert!((got - want).abs() < 1e-6, "{got} vs {want}");
    }
    let aligned = compare(&gt, &est, Alignment::Se3, 0.01).unwrap().summary;
    check(&aligned, 0.013470, 0.012024, 0.011183, 0.034760);
    for (got, want) in [(aligned.rmse_x, 0.010005), (aligned.rmse_y, 0.007606), (aligned.rmse_z, 0.004847)] {
        assert!((got - want).abs() < 1e-6, "{got} vs {want}");
    }
}

#[test]
fn agrees_with_evo_ape_sim3_on_a_monocular_estimate() {
    let gt = load("fr2_desk_groundtruth.txt");
    let est = load("fr2_desk_ORB.txt");
    let c = compare(&gt, &est, Alignment::Sim3, 0.01).unwrap();
    check(&c.summary, 0.006123, 0.005586, 0.005305, 0.021477);
}

#[test]
fn kitti_and_euroc_files_load_and_compare() {
    let gt = load("KITTI_00_gt.txt");
    let est = load("KITTI_00_ORB.txt");
    let c = compare(&gt, &est, Alignment::Se3, 0.01).unwrap();
    assert_eq!(c.summary.matched, gt.len().min(est.len()));
    let euroc = load("V102_groundtruth.csv");
    let c = compare(&euroc, &load("V102.txt"), Alignment::Se3, 0.01).unwrap();
    assert!(c.summary.matched > 100 && c.summary.ate_rmse < 0.5, "{:?}", c.summary);
}

#[test]
fn no_overlap_in_time_is_an_error() {
    let mut a = Trajectory::default();
    a.push(0.0, at(0.0, 0.0, 0.0));
    let mut b = Trajectory::default();
    b.push(5.0, at(0.0, 0.0, 0.0));
    let error = compare(&a, &b, Alignment::None, 0.01).unwrap_err();
    assert!(error.to_string().contains("no poses matched"), "{error}");
}
