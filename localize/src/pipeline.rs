//! The per-frame pipeline: a thin loop over the stages. For each frame the
//! odometry/IMU filter is advanced to the frame's time, the cloud gives
//! planes and 3D corners, the image gives 2D corners, the fused corners are
//! associated with the landmark map and correct the filter, and the map
//! grows with them.

use std::time::Instant;

use datasets::formats::{Calibration, PointCloud};
use datasets::math::{Pose3, Vec3};

use crate::config::LocalizeConfig;
use crate::ekf::Ekf;
use crate::error::Result;
use crate::fusion::CornerFusion;
use crate::geometry::{Geometry, GeometryStages};
use crate::landmarks::LandmarkMap;
use crate::plane_landmarks::{PlaneMap, RobotPlane};
use crate::pose::{Correspondence, PlaneCorrespondence, PlaneSigmas, PoseSolver};

/// How a frame's pose was obtained, written to the per-frame log.
#[derive(Debug, Clone, PartialEq)]
pub enum FrameStatus {
    /// Corrected by this many corner and wall correspondences.
    Fused { corners: usize, walls: usize },
    /// The first frame: the map starts at the reference pose.
    FirstFrame,
    /// Kept the odometry/IMU pose: too few corner and wall correspondences.
    TooFewMatches { corners: usize, walls: usize },
    /// No 2D corners (no image, or it failed): corrected by this many walls
    /// alone, or (0) the odometry/IMU pose kept.
    NoImage { why: String, walls: usize },
    /// Kept the odometry/IMU pose: the cloud was unusable.
    BadCloud(String),
}

impl FrameStatus {
    pub fn label(&self) -> String {
        match self {
            Self::Fused { corners, walls } => format!("fused: {corners} corners {walls} walls"),
            Self::FirstFrame => "first frame: map starts at the reference".into(),
            Self::TooFewMatches { corners, walls } => {
                format!("fallback to odometry/IMU: only {corners} corners {walls} walls")
            }
            Self::NoImage { why, walls: 0 } => format!("fallback to odometry/IMU: no 2D corners ({why})"),
            Self::NoImage { why, walls } => format!("walls only: {walls} walls; no 2D corners ({why})"),
            Self::BadCloud(why) => format!("fallback: bad cloud ({why})"),
        }
    }
}

/// Everything logged about one frame.
#[derive(Debug, Clone)]
pub struct FrameReport {
    pub stamp: f64,
    pub pose: Pose3,
    pub status: FrameStatus,
    pub detections: usize,
    pub planes: usize,
    pub corners: usize,
    pub matches: usize,
    pub correspondences: usize,
    pub plane_correspondences: usize,
    pub landmarks: usize,
    pub detect_ms: f64,
    pub normals_ms: f64,
    pub planes_ms: f64,
    pub corners_ms: f64,
    pub fusion_ms: f64,
    pub pose_ms: f64,
    pub total_ms: f64,
}

/// A frame's 2D corners and where the camera was when it saw them.
pub struct CameraCorners {
    /// The detected corners (or why there are none).
    pub pixels: std::result::Result<Vec<[f64; 2]>, String>,
    /// The camera at the image's own time, seen from the LIDAR at the scan's.
    pub lidar_from_camera: Pose3,
    /// The detector's own time.
    pub detect_ms: f64,
}

pub struct Localizer {
    geometry: GeometryStages,
    fusion: CornerFusion,
    solver: PoseSolver,
    pub map: LandmarkMap,
    pub plane_map: PlaneMap,
    calibration: Calibration,
    frames_seen: usize,
}

impl Localizer {
    pub fn new(config: &LocalizeConfig, calibration: Calibration) -> Result<Self> {
        Ok(Self {
            geometry: GeometryStages::new(config)?,
            fusion: CornerFusion::new(config.fusion.clone())?,
            solver: PoseSolver::new(config.pose.clone()),
            map: LandmarkMap::new(config.landmarks.clone()),
            plane_map: PlaneMap::new(config.plane_landmarks.clone()),
            calibration,
            frames_seen: 0,
        })
    }

    /// The planes and 3D corners of a frame's cloud (or why there are none).
    /// It depends on neither the filter nor the image, so it can run while
    /// the detector does (`run_sequence` runs the two side by side).
    pub fn frame_geometry(
        &self,
        cloud: std::result::Result<PointCloud, String>,
    ) -> std::result::Result<Geometry, String> {
        let cloud = match cloud {
            Ok(c) if c.is_empty() => return Err("no finite points".into()),
            Ok(c) => c,
            Err(why) => return Err(why),
        };
        let sensor = cloud.viewpoint.translation.vector;
        self.geometry.run(&cloud.points, &sensor).map_err(|e| e.to_string())
    }

    /// Processes one frame whose filter has been advanced to its time:
    /// `geometry` from `frame_geometry`, `camera` the image's corners,
    /// `started` when the frame's work began (its `total_ms` is the wall
    /// time since). The filter holds the fused pose after.
    pub fn process(
        &mut self,
        stamp: f64,
        ekf: &mut Ekf,
        geometry: std::result::Result<Geometry, String>,
        camera: CameraCorners,
        started: Instant,
    ) -> FrameReport {
        let CameraCorners { pixels, lidar_from_camera, detect_ms } = camera;
        let lidar_from_camera = &lidar_from_camera;
        let first = self.frames_seen == 0;
        self.frames_seen += 1;
        let mut report = FrameReport {
            stamp,
            pose: ekf.pose(),
            status: FrameStatus::FirstFrame,
            detections: pixels.as_ref().map_or(0, Vec::len),
            planes: 0,
            corners: 0,
            matches: 0,
            correspondences: 0,
            plane_correspondences: 0,
            landmarks: self.map.landmarks.len(),
            detect_ms,
            normals_ms: 0.0,
            planes_ms: 0.0,
            corners_ms: 0.0,
            fusion_ms: 0.0,
            pose_ms: 0.0,
            total_ms: 0.0,
        };
        let finish = |mut report: FrameReport, ekf: &Ekf, status: FrameStatus| {
            report.pose = ekf.pose();
            report.status = status;
            report.total_ms = started.elapsed().as_secs_f64() * 1e3;
            report
        };
        let geometry = match geometry {
            Ok(g) => g,
            Err(why) => return finish(report, ekf, FrameStatus::BadCloud(why)),
        };
        report.normals_ms = geometry.normals_ms;
        report.planes_ms = geometry.planes_ms;
        report.corners_ms = geometry.corners_ms;
        report.planes = geometry.planes.planes.len();
        report.corners = geometry.corners.corners.len();
        let predicted = ekf.pose();
        let robot_from_lidar = self.calibration.robot_from_lidar;
        let robot_planes: Vec<RobotPlane> =
            geometry.planes.planes.iter().map(|p| RobotPlane::from_lidar(p, &robot_from_lidar)).collect();
        let plane_matches = self.plane_correspondences(&robot_planes, &predicted);
        report.plane_correspondences = plane_matches.len();
        let pixels = match pixels {
            Ok(p) => p,
            Err(why) => {
                // Walls can still correct the pose; corners cannot be found.
                let corrected =
                    !first && self.solver.correct_with_planes(ekf, &[], &plane_matches, self.plane_sigmas()).is_some();
                self.observe_planes(&robot_planes, &ekf.pose());
                let walls = if corrected { plane_matches.len() } else { 0 };
                return finish(report, ekf, FrameStatus::NoImage { why, walls });
            }
        };
        let fusion_start = Instant::now();
        let matches = self.fusion.fuse(
            &pixels,
            &self.calibration.camera,
            lidar_from_camera,
            &geometry.planes,
            &geometry.corners,
            &geometry.points,
        );
        report.matches = matches.len();
        let in_robot: Vec<Vec3> = matches
            .iter()
            .map(|m| self.calibration.robot_from_lidar * nalgebra::Point3::from(m.position))
            .map(|p| p.coords)
            .collect();
        let in_world: Vec<Vec3> = in_robot.iter().map(|c| (predicted * nalgebra::Point3::from(*c)).coords).collect();
        let association = self.map.associate(&in_world);
        let correspondences: Vec<Correspondence> = in_robot
            .iter()
            .zip(&association)
            .filter_map(|(c, a)| {
                a.filter(|&k| self.map.is_trusted(k))
                    .map(|k| Correspondence { in_robot: *c, in_world: self.map.landmarks[k].position })
            })
            .collect();
        report.fusion_ms = fusion_start.elapsed().as_secs_f64() * 1e3;
        report.correspondences = correspondences.len();
        let pose_start = Instant::now();
        let status = if first {
            FrameStatus::FirstFrame
        } else {
            let (corners, walls) = (correspondences.len(), plane_matches.len());
            match self.solver.correct_with_planes(ekf, &correspondences, &plane_matches, self.plane_sigmas()) {
                Some(_) => FrameStatus::Fused { corners, walls },
                None => FrameStatus::TooFewMatches { corners, walls },
            }
        };
        // The map grows with the corners placed by the corrected pose.
        let corrected = ekf.pose();
        let in_world: Vec<Vec3> = in_robot.iter().map(|c| (corrected * nalgebra::Point3::from(*c)).coords).collect();
        let association = self.map.associate(&in_world);
        self.map.observe(&in_world, &association);
        self.observe_planes(&robot_planes, &corrected);
        report.pose_ms = pose_start.elapsed().as_secs_f64() * 1e3;
        report.landmarks = self.map.landmarks.len();
        finish(report, ekf, status)
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
                let landmark = &self.plane_map.landmarks[k];
                let same_side = (predicted.rotation * plane.normal).dot(&landmark.normal) >= 0.0;
                Some(PlaneCorrespondence {
                    normal_in_robot: if same_side { plane.normal } else { -plane.normal },
                    point_in_robot: plane.point,
                    normal_in_world: landmark.normal,
                    distance_in_world: landmark.distance,
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
