//! The per-frame pipeline: a thin loop over the stages. For each frame the
//! odometry/IMU filter is advanced to the frame's time, the cloud gives
//! planes and 3D corners, the image gives 2D corners, the fused corners are
//! associated with the landmark map and correct the filter, and the map
//! grows with them.

use std::time::Instant;

use datasets::io::formats::{Calibration, PointCloud};
use datasets::math::{Pose3, Vec3};
use nalgebra::Point3;

use crate::config::LocalizeConfig;
use crate::error::Result;
use crate::estimation::edge_map::EdgeMap;
use crate::estimation::ekf::Ekf;
use crate::estimation::fusion::CornerFusion;
use crate::estimation::landmarks::LandmarkMap;
use crate::estimation::level_floor::{LevelFloorConfig, read_floor};
use crate::estimation::plane_landmarks::{PlaneMap, RobotPlane};
use crate::estimation::point_map::PointMap;
use crate::estimation::pose::{Correspondence, PlaneCorrespondence, PlaneSigmas, PoseSolver};
use crate::estimation::relocalize::{Placement, RelocalizeConfig, relocalize};
use crate::estimation::scan_match::{ScanFix, ScanMatcher, ScanPoints};
use crate::input::frame_fault::FrameFault;
use crate::scan::geometry::{Geometry, GeometryStages};
use crate::scan::range_image::RangeImage;

/// How a frame's pose was obtained, written to the per-frame log.
#[derive(Debug, Clone, PartialEq)]
pub enum FrameStatus {
    /// Corrected by this many corner, wall and scan-to-map point
    /// correspondences (0 scan points: no registration).
    Fused { corners: usize, walls: usize, scan: usize },
    /// The first frame: the map starts at the reference pose.
    FirstFrame,
    /// Kept the odometry/IMU pose: too few corner and wall correspondences.
    TooFewMatches { corners: usize, walls: usize },
    /// No 2D corners (no image, or it failed): corrected by this many walls
    /// and scan points alone, or (both 0) the odometry/IMU pose kept.
    NoImage { why: FrameFault, walls: usize, scan: usize },
    /// Kept the odometry/IMU pose: the cloud was unusable.
    BadCloud(FrameFault),
}

impl FrameStatus {
    /// Whether corners, walls or the scan registration corrected the frame's
    /// pose (rather than it being the odometry/IMU's).
    pub fn corrected(&self) -> bool {
        match self {
            Self::Fused { .. } => true,
            Self::NoImage { walls, scan, .. } => *walls > 0 || *scan > 0,
            Self::FirstFrame | Self::TooFewMatches { .. } | Self::BadCloud(_) => false,
        }
    }

    pub fn label(&self) -> String {
        match self {
            Self::Fused { corners, walls, scan } => {
                format!("fused: {corners} corners {walls} walls {scan} scan points")
            }
            Self::FirstFrame => "first frame: map starts at the reference".into(),
            Self::TooFewMatches { corners, walls } => {
                format!("fallback to odometry/IMU: only {corners} corners {walls} walls")
            }
            Self::NoImage { why, walls: 0, scan: 0 } => format!("fallback to odometry/IMU: no 2D corners ({why})"),
            Self::NoImage { why, walls, scan } => {
                format!("LIDAR only: {walls} walls {scan} scan points; no 2D corners ({why})")
            }
            Self::BadCloud(why) => format!("fallback: bad cloud ({why})"),
        }
    }
}

/// Everything logged about one frame.
#[derive(Debug, Clone)]
pub struct FrameReport {
    pub stamp: f64,
    /// Seconds since the previous scan (0 for the first): a LIDAR gap shows here.
    pub scan_gap_s: f64,
    pub pose: Pose3,
    pub status: FrameStatus,
    pub detections: usize,
    pub planes: usize,
    pub corners: usize,
    pub matches: usize,
    pub correspondences: usize,
    pub plane_correspondences: usize,
    /// Scan points registered against the point map (0: no registration).
    pub scan_correspondences: usize,
    /// A level floor levelled roll and pitch.
    pub level_floor: bool,
    pub landmarks: usize,
    pub detect_ms: f64,
    pub normals_ms: f64,
    pub planes_ms: f64,
    pub corners_ms: f64,
    pub fusion_ms: f64,
    pub scan_ms: f64,
    pub pose_ms: f64,
    pub total_ms: f64,
}

impl FrameReport {
    /// A frame's report before its stages ran: the pose is the filter's.
    fn new(stamp: f64, scan_gap_s: f64, pose: Pose3, detections: usize, landmarks: usize, detect_ms: f64) -> Self {
        Self {
            stamp,
            scan_gap_s,
            pose,
            status: FrameStatus::FirstFrame,
            detections,
            planes: 0,
            corners: 0,
            matches: 0,
            correspondences: 0,
            plane_correspondences: 0,
            scan_correspondences: 0,
            level_floor: false,
            landmarks,
            detect_ms,
            normals_ms: 0.0,
            planes_ms: 0.0,
            corners_ms: 0.0,
            fusion_ms: 0.0,
            scan_ms: 0.0,
            pose_ms: 0.0,
            total_ms: 0.0,
        }
    }

    fn record_geometry(&mut self, geometry: &Geometry) {
        self.normals_ms = geometry.normals_ms;
        self.planes_ms = geometry.planes_ms;
        self.corners_ms = geometry.corners_ms;
        self.planes = geometry.planes.planes.len();
        self.corners = geometry.corners.corners.len();
    }

    /// The report with the filter's pose after the frame and how it came about.
    fn finish(mut self, ekf: &Ekf, status: FrameStatus, started: Instant) -> Self {
        self.pose = ekf.pose();
        self.status = status;
        self.total_ms = elapsed_ms(started);
        self
    }
}

fn elapsed_ms(since: Instant) -> f64 {
    since.elapsed().as_secs_f64() * 1e3
}

/// Robot-frame points placed in the world by `pose`.
fn in_world(in_robot: &[Vec3], pose: &Pose3) -> Vec<Vec3> {
    in_robot.iter().map(|c| (pose * nalgebra::Point3::from(*c)).coords).collect()
}

/// A frame's 2D corners and where the camera was when it saw them.
pub struct CameraCorners {
    /// The detected corners (or why there are none).
    pub pixels: std::result::Result<Vec<[f64; 2]>, FrameFault>,
    /// The camera at the image's own time, seen from the LIDAR at the scan's.
    pub lidar_from_camera: Pose3,
    /// The detector's own time.
    pub detect_ms: f64,
    /// The image's edges lifted through a registered depth image, in the
    /// LIDAR's (the depth camera's) frame; empty without.
    pub edges: Vec<Point3<f32>>,
}

pub struct Localizer {
    geometry: GeometryStages,
    fusion: CornerFusion,
    solver: PoseSolver,
    pub map: LandmarkMap,
    pub plane_map: PlaneMap,
    scan_matcher: ScanMatcher,
    pub point_map: PointMap,
    pub edge_map: EdgeMap,
    calibration: Calibration,
    frames_seen: usize,
    last_stamp: Option<f64>,
    /// The last frame's corrected pose: a registration start.
    previous_pose: Option<Pose3>,
    /// The maps came from an earlier run: the first frame is corrected
    /// against them rather than starting them.
    given_map: bool,
    /// The given map's keyframes, where its first frame is searched for.
    keyframes: Vec<Pose3>,
    relocalize: RelocalizeConfig,
    level_floor: LevelFloorConfig,
}

/// How far from a given start's heading the search turns.
const START_WINDOW_DEG: f64 = 30.0;
/// Variance of a start taken as given, unsearched (0.1 m, 0.1 rad).
const START_UNSEARCHED_VARIANCE: f64 = 0.01;

impl Localizer {
    pub fn new(config: &LocalizeConfig, calibration: Calibration) -> Result<Self> {
        let scan_matcher = ScanMatcher::new(config.scan_match.clone())?;
        Ok(Self {
            geometry: config.geometry_stages()?,
            fusion: CornerFusion::new(config.fusion.clone())?,
            solver: PoseSolver::new(config.pose.clone()),
            map: LandmarkMap::new(config.landmarks.clone()),
            plane_map: PlaneMap::new(config.plane_landmarks.clone()),
            point_map: scan_matcher.new_map(),
            edge_map: scan_matcher.new_edge_map(),
            scan_matcher,
            calibration,
            frames_seen: 0,
            last_stamp: None,
            previous_pose: None,
            given_map: false,
            keyframes: Vec::new(),
            relocalize: config.relocalize.clone(),
            level_floor: config.level_floor.clone(),
        })
    }

    /// Starts from the maps an earlier run wrote (`map_output::read_map`);
    /// the first frame is then placed in them (`place_in_map`).
    pub fn start_from_map(&mut self, map: crate::map_output::SavedMap) {
        self.keyframes = map.keyframes;
        self.map.landmarks = map.corners;
        self.plane_map.landmarks = map.walls;
        self.plane_map.axis = map.wall_axis;
        let (points, normals): (Vec<Vec3>, Vec<Vec3>) = map.points.iter().map(|p| (p.position, p.normal)).unzip();
        self.point_map.insert(&points, &normals, &Pose3::identity());
        self.given_map = true;
    }

    /// Where the frame of `geometry` lies in the given map: searched near
    /// `start` when the user gave one (within `START_WINDOW_DEG` of its
    /// heading), else around every keyframe of the map at every heading. A
    /// map without surface points cannot be searched: a given start is then
    /// taken as it is.
    pub fn place_in_map(&self, geometry: &Geometry, start: Option<&Pose3>) -> std::result::Result<Placement, String> {
        if self.point_map.is_empty() {
            let Some(start) = start else {
                return Err(
                    "the map has no surface points to search (written with scan matching off): give --start-pose"
                        .into(),
                );
            };
            let covariance = nalgebra::Matrix6::from_diagonal_element(START_UNSEARCHED_VARIANCE);
            return Ok(Placement { pose: *start, agreement: 0.0, runner_up: 0.0, candidates: 0, covariance });
        }
        if !self.scan_matcher.config().enabled {
            return Err("placing a scan in the map needs scan matching (`scan_match.enabled`)".into());
        }
        let scan = self.scan_points(geometry, &[]);
        let (seeds, window_deg) = match start {
            Some(pose) => (std::slice::from_ref(pose), START_WINDOW_DEG),
            None => (self.keyframes.as_slice(), 180.0),
        };
        relocalize(&self.point_map, &scan, seeds, window_deg, self.scan_matcher.config(), &self.relocalize)
    }

    /// The planes and 3D corners of a frame's cloud (or why there are none).
    /// It depends on neither the filter nor the image, so it can run while
    /// the detector does (`run_sequence` runs the two side by side).
    pub fn frame_geometry(
        &self,
        cloud: std::result::Result<PointCloud, FrameFault>,
        sweep_image: Option<(RangeImage, f64)>,
    ) -> std::result::Result<Geometry, FrameFault> {
        let cloud = match cloud {
            Ok(c) if c.is_empty() => return Err(FrameFault::NoFinitePoints),
            Ok(c) => c,
            Err(why) => return Err(why),
        };
        let sensor = cloud.viewpoint.translation.vector;
        let image = sweep_image.or_else(|| self.geometry.range_image(&cloud.points, &sensor));
        self.geometry.run_on(&cloud.points, &sensor, image).map_err(|e| FrameFault::Geometry(e.to_string()))
    }

    /// The rows and columns of a sweep as it came (before deskewing), for
    /// `frame_geometry`.
    pub fn sweep_image(&self, cloud: &PointCloud) -> Option<(RangeImage, f64)> {
        self.geometry.range_image(&cloud.points, &cloud.viewpoint.translation.vector)
    }

    /// Processes one frame whose filter has been advanced to its time:
    /// `geometry` from `frame_geometry`, `camera` the image's corners,
    /// `started` when the frame's work began (its `total_ms` is the wall
    /// time since). The filter holds the fused pose after.
    pub fn process(
        &mut self,
        stamp: f64,
        ekf: &mut Ekf,
        geometry: std::result::Result<Geometry, FrameFault>,
        camera: CameraCorners,
        started: Instant,
    ) -> FrameReport {
        let CameraCorners { pixels, lidar_from_camera, detect_ms, edges } = camera;
        // The first frame anchors the maps at the reference pose.
        let first = self.frames_seen == 0 && !self.given_map;
        self.frames_seen += 1;
        let scan_gap_s = self.last_stamp.map_or(0.0, |t| stamp - t);
        self.last_stamp = Some(stamp);
        let detections = pixels.as_ref().map_or(0, Vec::len);
        let mut report =
            FrameReport::new(stamp, scan_gap_s, ekf.pose(), detections, self.map.landmarks.len(), detect_ms);
        // Without the cloud's planes and corners the filter's pose stands.
        let geometry = match geometry {
            Ok(g) => g,
            Err(why) => return report.finish(ekf, FrameStatus::BadCloud(why), started),
        };
        report.record_geometry(&geometry);
        // A level floor in sight levels the attitude before anything is paired.
        if let Some(floor) = read_floor(&self.level_floor, &geometry, &self.calibration.robot_from_lidar, &ekf.pose()) {
            report.level_floor = ekf.update_level(&floor.normal_in_robot, floor.sigma_rad, self.level_floor.gate_chi2);
        }
        // Walls: the frame's planes paired with the plane landmarks at the predicted pose.
        let predicted = ekf.pose();
        let planes = self.robot_planes(&geometry);
        let walls = self.plane_correspondences(&planes, &predicted);
        report.plane_correspondences = walls.len();
        // The scan against the point map, from the predicted pose.
        let scan_start = Instant::now();
        let scan_points = self.scan_points(&geometry, &edges);
        let scan = self.register(&scan_points, ekf);
        report.scan_correspondences = scan.map_or(0, |s| s.correspondences);
        report.scan_ms = elapsed_ms(scan_start);
        // Without 2D corners the walls and the scan alone correct the pose.
        let pixels = match pixels {
            Ok(p) => p,
            Err(why) => {
                let status = self.correct_without_corners(ekf, first, &planes, &walls, scan.as_ref(), why);
                self.insert_scan(&scan_points, &ekf.pose());
                return report.finish(ekf, status, started);
            }
        };
        // Fusion: the 2D corners cast into the cloud, paired with corner landmarks.
        let fusion_start = Instant::now();
        let (corners_in_robot, corners) =
            self.corner_correspondences(&pixels, &lidar_from_camera, &geometry, &predicted);
        report.matches = corners_in_robot.len();
        report.correspondences = corners.len();
        report.fusion_ms = elapsed_ms(fusion_start);
        // Corners and walls correct the filter; the maps grow with what the corrected pose places.
        let pose_start = Instant::now();
        let status = if first { FrameStatus::FirstFrame } else { self.correct(ekf, &corners, &walls, scan.as_ref()) };
        self.grow_maps(&corners_in_robot, &planes, &ekf.pose());
        self.insert_scan(&scan_points, &ekf.pose());
        report.pose_ms = elapsed_ms(pose_start);
        report.landmarks = self.map.landmarks.len();
        report.finish(ekf, status, started)
    }

    /// The frame's planes in the robot frame.
    fn robot_planes(&self, geometry: &Geometry) -> Vec<RobotPlane> {
        let robot_from_lidar = self.calibration.robot_from_lidar;
        geometry.planes.planes.iter().map(|p| RobotPlane::from_lidar(p, &robot_from_lidar)).collect()
    }

    /// A frame without 2D corners: its walls and scan correct the pose
    /// (except on the first frame) and its walls join the plane map.
    fn correct_without_corners(
        &mut self,
        ekf: &mut Ekf,
        first: bool,
        planes: &[RobotPlane],
        walls: &[PlaneCorrespondence],
        scan: Option<&ScanFix>,
        why: FrameFault,
    ) -> FrameStatus {
        let corrected = !first && self.solver.correct_with_planes(ekf, &[], walls, self.plane_sigmas(), scan).is_some();
        self.observe_planes(planes, &ekf.pose());
        let (walls, scan) = if corrected { (walls.len(), scan.map_or(0, |s| s.correspondences)) } else { (0, 0) };
        FrameStatus::NoImage { why, walls, scan }
    }

    /// The frame's planar points and `edges` (LIDAR frame) for scan
    /// matching (none when it is off).
    fn scan_points(&self, geometry: &Geometry, edges: &[Point3<f32>]) -> ScanPoints {
        if !self.scan_matcher.config().enabled {
            return ScanPoints::default();
        }
        let robot_from_lidar = &self.calibration.robot_from_lidar;
        let mut scan =
            ScanPoints::select(self.scan_matcher.config(), &geometry.points, &geometry.normals, robot_from_lidar);
        scan.edges = edges.iter().map(|p| robot_from_lidar.transform_point(&p.cast::<f64>()).coords).collect();
        scan
    }

    /// The scan registered against the point map from the filter's pose
    /// (and from the last frame's across a wide baseline).
    fn register(&self, scan: &ScanPoints, ekf: &Ekf) -> Option<ScanFix> {
        if scan.points.is_empty() {
            return None;
        }
        let previous = self.previous_pose.as_ref();
        let predicted = crate::estimation::ekf::pose_vector(&ekf.x);
        self.scan_matcher.register_after(&self.point_map, Some(&self.edge_map), scan, &predicted, previous)
    }

    /// The frame's points join the maps at its corrected pose.
    fn insert_scan(&mut self, scan: &ScanPoints, pose: &Pose3) {
        self.point_map.insert(&scan.points, &scan.normals, pose);
        self.edge_map.insert(&scan.edges, pose);
        self.previous_pose = Some(*pose);
    }

    /// The 2D corners matched to the cloud's 3D corners (in the robot frame)
    /// and those of them associated with trusted corner landmarks at the
    /// predicted pose.
    fn corner_correspondences(
        &self,
        pixels: &[[f64; 2]],
        lidar_from_camera: &Pose3,
        geometry: &Geometry,
        predicted: &Pose3,
    ) -> (Vec<Vec3>, Vec<Correspondence>) {
        let matches = self.fusion.fuse(
            pixels,
            &self.calibration.camera,
            lidar_from_camera,
            &geometry.planes,
            &geometry.corners,
            &geometry.points,
        );
        let in_robot: Vec<Vec3> = matches
            .iter()
            .map(|m| (self.calibration.robot_from_lidar * nalgebra::Point3::from(m.position)).coords)
            .collect();
        let association = self.map.associate(&in_world(&in_robot, predicted));
        let correspondences = in_robot
            .iter()
            .zip(&association)
            .filter_map(|(c, a)| {
                a.filter(|&k| self.map.is_trusted(k))
                    .map(|k| Correspondence { in_robot: *c, in_world: self.map.landmarks[k].position })
            })
            .collect();
        (in_robot, correspondences)
    }

    /// Corrects the filter with corner, wall and scan correspondences.
    fn correct(
        &self,
        ekf: &mut Ekf,
        corners: &[Correspondence],
        walls: &[PlaneCorrespondence],
        scan: Option<&ScanFix>,
    ) -> FrameStatus {
        let (c, w) = (corners.len(), walls.len());
        match self.solver.correct_with_planes(ekf, corners, walls, self.plane_sigmas(), scan) {
            Some(_) => FrameStatus::Fused { corners: c, walls: w, scan: scan.map_or(0, |s| s.correspondences) },
            None => FrameStatus::TooFewMatches { corners: c, walls: w },
        }
    }

    /// The corner and plane maps take the frame's corners and planes placed
    /// by `pose`.
    fn grow_maps(&mut self, corners_in_robot: &[Vec3], planes: &[RobotPlane], pose: &Pose3) {
        let corners = in_world(corners_in_robot, pose);
        let association = self.map.associate(&corners);
        self.map.observe(&corners, &association);
        self.observe_planes(planes, pose);
    }

    fn plane_sigmas(&self) -> PlaneSigmas {
        let c = &self.plane_map.config;
        PlaneSigmas { distance_m: c.distance_sigma_m, normal_rad: c.normal_sigma_rad }
    }

    /// Frame planes paired with trusted plane landmarks (none when plane
    /// landmarks are off).
    fn plane_correspondences(&self, planes: &[RobotPlane], predicted: &Pose3) -> Vec<PlaneCorrespondence> {
        if !self.plane_map.config.enabled {
            return Vec::new();
        }
        let association = self.plane_map.associate(planes, predicted);
        planes
            .iter()
            .zip(&association)
            .filter_map(|(plane, a)| {
                let k = (*a)?;
                if !self.plane_map.is_trusted(k) {
                    return None;
                }
                let (normal, distance) = self.plane_map.plane(k);
                let same_side = (predicted.rotation * plane.normal).dot(&normal) >= 0.0;
                Some(PlaneCorrespondence {
                    normal_in_robot: if same_side { plane.normal } else { -plane.normal },
                    point_in_robot: plane.point,
                    normal_in_world: normal,
                    distance_in_world: distance,
                })
            })
            .collect()
    }

    fn observe_planes(&mut self, planes: &[RobotPlane], pose: &Pose3) {
        if self.plane_map.config.enabled {
            let association = self.plane_map.associate(planes, pose);
            self.plane_map.observe(planes, &association, pose);
        }
    }
}
