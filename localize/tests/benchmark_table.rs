//! The benchmark's flags and tables: lists parse or fail with the bad part
//! named, plans outside the supported ranges are refused, and the tables
//! carry each figure in its unit (Markdown in mm, CSV in m).

use localize::evaluation::benchmark::{
    BenchmarkPlan, BenchmarkRow, SequenceRecord, csv, markdown, parse_buildings, parse_speeds,
};
use localize::evaluation::eval::ErrorSummary;

#[test]
fn building_and_speed_lists_parse_or_name_the_bad_part() {
    assert_eq!(parse_buildings("1-5").unwrap(), vec![1, 2, 3, 4, 5]);
    assert_eq!(parse_buildings("2, 4,7-8").unwrap(), vec![2, 4, 7, 8]);
    assert!(parse_buildings("1-x").unwrap_err().contains("`x`"));
    assert!(parse_buildings("5-1").unwrap_err().contains("5-1"));
    assert!(parse_buildings("-3").unwrap_err().contains("`-3`: building numbers are whole numbers from 0"));
    assert!(parse_buildings("1-100000").is_err());
    assert_eq!(parse_speeds("0.05,0.5,1.0").unwrap(), vec![0.05, 0.5, 1.0]);
    assert!(parse_speeds("0.5,fast").unwrap_err().contains("`fast`"));
}

#[test]
fn plans_outside_the_supported_ranges_are_refused() {
    assert!(BenchmarkPlan::standard().validate().is_ok());
    assert!(BenchmarkPlan::quick().validate().is_ok());
    let with = |f: &dyn Fn(&mut BenchmarkPlan)| {
        let mut plan = BenchmarkPlan::quick();
        f(&mut plan);
        plan.validate()
    };
    let far = with(&|p| p.buildings = vec![2_000_000]).unwrap_err();
    assert!(far.field == "buildings" && far.problem.contains("building 2000000"), "{far}");
    assert!(with(&|p| p.buildings = vec![0]).is_ok(), "the paper's building runs beside the generated ones");
    let nan = with(&|p| p.speeds_mps = vec![f64::NAN]).unwrap_err();
    assert!(nan.field == "speeds_mps" && nan.problem.contains("NaN"), "{nan}");
    assert!(with(&|p| p.speeds_mps = vec![3.0]).is_err());
    assert!(with(&|p| p.max_scans = 5).is_err());
    assert!(with(&|p| p.buildings.clear()).is_err());
    // Generated buildings get a robot's timing; the first speed also renders the AP images.
    let data = BenchmarkPlan::standard().datagen(3, 7, 0.5, true);
    assert_eq!((data.world.building, data.sequence.speed_mps, data.sequence.max_scans), (3, 0.5, Some(600)));
    assert_eq!(
        (data.sequence.rate_hz, data.sequence.camera_rate_hz, data.lidar.sweep_period_s),
        (10.0, Some(15.0), 0.1)
    );
    assert_eq!((data.detection.images, data.detection.train), (60, 0));
    assert_eq!(BenchmarkPlan::standard().datagen(3, 7, 1.0, false).detection.images, 0);
    let paper = BenchmarkPlan::standard().datagen(0, 7, 0.05, true);
    assert_eq!((paper.sequence.rate_hz, paper.sequence.camera_rate_hz, paper.lidar.sweep_period_s), (1.0, None, 0.0));
    // More seeds for the paper's building only, the plan's own first and once.
    let mut plan = BenchmarkPlan::standard();
    plan.paper_seeds = vec![8, 7, 9, 8];
    assert_eq!(plan.seeds_of(0), vec![7, 8, 9]);
    assert_eq!(plan.seeds_of(3), vec![7]);
    assert_eq!(plan.datagen(0, 9, 0.05, true).seed, 9);
}

fn summary(x: f64, y: f64, z: f64) -> ErrorSummary {
    let ate = (x * x + y * y + z * z).sqrt();
    ErrorSummary {
        matched: 10,
        rmse_x: x,
        rmse_y: y,
        rmse_z: z,
        ate_rmse: ate,
        ate_mean: ate,
        ate_median: ate,
        ate_max: ate,
    }
}

#[test]
fn tables_carry_each_figure_in_its_unit() {
    let row = BenchmarkRow {
        building: 2,
        seed: 7,
        speed_mps: 0.5,
        levels: 3,
        scans: 600,
        distance_m: 29.95,
        fused: summary(0.003, 0.004, 0.012),
        odometry_imu: summary(0.1, 0.2, 0.2),
        without_camera: summary(0.006, 0.008, 0.024),
        without_scan_match: summary(0.0, 0.03, 0.04),
        lidar_alone: summary(0.01, 0.02, 0.05),
        corrected_frames: 590,
        ms_per_frame: 71.25,
        ap50: Some(0.81234),
        peers: vec![("kiss-icp".into(), None), ("genz-icp".into(), Some(summary(0.02, 0.03, 0.06)))],
    };
    let md = markdown(std::slice::from_ref(&row));
    let lines: Vec<&str> = md.lines().collect();
    assert_eq!(lines.len(), 3);
    let header: Vec<&str> = lines[0].split('|').map(str::trim).collect();
    let cells: Vec<&str> = lines[2].split('|').map(str::trim).collect();
    assert_eq!(header.len(), cells.len());
    let cell = |name: &str| cells[header.iter().position(|h| *h == name).unwrap_or_else(|| panic!("{name}"))];
    assert_eq!(cell("seed"), "7");
    assert_eq!(cell("fused x"), "3.0");
    assert_eq!(cell("fused z"), "12.0");
    assert_eq!(cell("fused ATE"), "13.0");
    assert_eq!(cell("odom/IMU ATE"), "300.0");
    assert_eq!(cell("without camera ATE"), "26.0");
    assert_eq!(cell("without scan matching ATE"), "50.0");
    assert_eq!(cell("LIDAR alone ATE"), "54.8");
    assert_eq!(cell("kiss-icp ATE"), "-");
    assert_eq!(cell("genz-icp y"), "30.0");
    assert_eq!(cell("genz-icp ATE"), "70.0");
    assert_eq!(cell("corrected"), "590/600");
    assert_eq!(cell("AP@0.5"), "0.812");
    let table = csv(&[row]);
    let mut lines = table.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let cells: Vec<&str> = lines.next().unwrap().split(',').collect();
    assert_eq!(header.len(), cells.len());
    let cell = |name: &str| cells[header.iter().position(|h| *h == name).unwrap_or_else(|| panic!("{name}"))];
    assert_eq!(cell("fused_ate"), "0.013000");
    assert_eq!(cell("without_scan_match_ate"), "0.050000");
    assert_eq!(cell("lidar_alone_ate"), "0.054772");
    assert_eq!(cell("kiss_icp_ate"), "");
    assert_eq!(cell("genz_icp_rmse_x"), "0.020000");
    assert_eq!(cell("ap50"), "0.8123");
}

#[test]
fn a_sequence_run_is_reused_only_when_what_made_it_is_the_same() {
    let dir = tempfile::tempdir().unwrap();
    let record = SequenceRecord {
        fused: summary(0.003, 0.004, 0.012),
        odometry_imu: summary(0.1, 0.2, 0.2),
        without_camera: summary(0.006, 0.008, 0.024),
        without_scan_match: summary(0.0, 0.03, 0.04),
        lidar_alone: summary(0.01, 0.02, 0.05),
        scans: 600,
        corrected_frames: 590,
        ms_per_frame: 71.25,
        ap50: Some(0.812_345_678_9),
    };
    let inputs = serde_json::json!({ "data": { "seed": 7 }, "made_by": { "program": "0123" }, "ap50": true });
    assert_eq!(SequenceRecord::read(dir.path(), &inputs), None, "nothing to reuse yet");
    record.write(dir.path(), &inputs).unwrap();
    assert_eq!(SequenceRecord::read(dir.path(), &inputs), Some(record.clone()));
    let rebuilt = serde_json::json!({ "data": { "seed": 7 }, "made_by": { "program": "4567" }, "ap50": true });
    assert_eq!(SequenceRecord::read(dir.path(), &rebuilt), None, "another program redoes the run");
    std::fs::write(dir.path().join("benchmark-run.json"), "{ \"inputs\": ").unwrap();
    assert_eq!(SequenceRecord::read(dir.path(), &inputs), None, "a torn record redoes the run");
}
