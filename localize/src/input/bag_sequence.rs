//! A ROS bag as a sequence: each role (LIDAR, camera, camera_info, IMU,
//! odometry, ground truth) is the one topic of its message type, or the
//! topic the user names; the calibration comes from `/tf_static` and
//! `camera_info` (or a `calib.json`); a frame is a LIDAR scan with the
//! nearest image within the tolerance, read in one pass over the file.
//!
//! Every time is the sensor's header stamp on the recording's own clock.

use std::collections::{HashMap, VecDeque};
use std::path::{Path, PathBuf};

use datasets::camera::PinholeCamera;
use datasets::io::formats::{Calibration, ImuSample, OdometrySample, Trajectory, read_calibration};
use datasets::io::recording::messages::{MessageKind, camera_info, geometry, image, point_cloud};
use datasets::io::recording::pose_topic::{POSE_KINDS, stamped_pose};
use datasets::io::recording::tf_tree::TfTree;
use datasets::io::recording::{RawMessage, Recording};
use datasets::math::Pose3;
use datasets::undistort::Undistorter;

use crate::error::{LocalizeError, Result};
use crate::input::frame_fault::FrameFault;
use crate::input::rgbd_sequence::{DepthOptions, optical_from_body};
use crate::input::sequence::RangeSensor;
use crate::input::sequence::{FrameImage, FrameInput, MotionLog, SensorSequence, SyncConfig, nearest_within};

/// Which topics and frames to use; `None` finds the topic by its type.
#[derive(Debug, Clone, Default)]
pub struct BagOptions {
    pub lidar_topic: Option<String>,
    pub image_topic: Option<String>,
    pub camera_info_topic: Option<String>,
    pub imu_topic: Option<String>,
    pub odom_topic: Option<String>,
    pub gt_topic: Option<String>,
    /// A depth image topic (`sensor_msgs/Image`) as the 3D sensor.
    pub depth_topic: Option<String>,
    /// How a depth image becomes a scan.
    pub depth: DepthOptions,
    /// The robot's frame (`base_link` when not given).
    pub base_frame: Option<String>,
    /// A `calib.json` that replaces the recording's calibration.
    pub calib: Option<PathBuf>,
}

/// The topic (index into the recording's topics) of each role.
#[derive(Debug, Clone, PartialEq)]
pub struct Roles {
    /// The 3D sensor's topic: a LIDAR's clouds or a depth camera's images.
    pub lidar: usize,
    pub range: RangeSensor,
    /// The depth camera's camera_info (its intrinsics), for a depth camera.
    pub depth_info: Option<usize>,
    pub image: Option<usize>,
    pub camera_info: Option<usize>,
    pub imu: Option<usize>,
    pub odometry: Option<usize>,
    pub ground_truth: Option<usize>,
    pub tf_static: Option<usize>,
    pub tf: Option<usize>,
}

fn bag_error(recording: &Recording, message: impl Into<String>) -> LocalizeError {
    LocalizeError::Sequence { path: recording.path.clone(), message: message.into() }
}

fn kinds_of(recording: &Recording, kinds: &[MessageKind]) -> Vec<usize> {
    (0..recording.topics.len()).filter(|&k| recording.topics[k].kind().is_some_and(|m| kinds.contains(&m))).collect()
}

/// One role's topic: the named one (which must exist and have a fitting
/// type), else the only topic of a fitting type; `Ok(None)` when there is none.
fn pick(
    recording: &Recording,
    role: &str,
    flag: &str,
    named: Option<&str>,
    kinds: &[MessageKind],
    candidates: Vec<usize>,
) -> Result<Option<usize>> {
    let type_list = kinds.iter().map(|k| format!("{k:?}")).collect::<Vec<_>>().join(" or ");
    if let Some(name) = named {
        let k = recording.topic(name).ok_or_else(|| bag_error(recording, format!("{flag} {name}: no such topic")))?;
        if !recording.topics[k].kind().is_some_and(|m| kinds.contains(&m)) {
            return Err(bag_error(
                recording,
                format!(
                    "{flag} {name}: the topic is {}, the {role} must be {type_list}",
                    recording.topics[k].type_name
                ),
            ));
        }
        return Ok(Some(k));
    }
    match candidates.as_slice() {
        [] => Ok(None),
        [k] => Ok(Some(*k)),
        several => {
            let names: Vec<String> = several
                .iter()
                .map(|&k| format!("{} ({})", recording.topics[k].name, recording.topics[k].type_name))
                .collect();
            Err(bag_error(
                recording,
                format!("several topics could be the {role}: {}; choose one with {flag}", names.join(", ")),
            ))
        }
    }
}

/// The roles of a recording's topics, and a line for each choice.
pub fn find_roles(recording: &Recording, options: &BagOptions) -> Result<(Roles, Vec<String>)> {
    use MessageKind::*;
    let non_empty = |kinds: &[MessageKind]| -> Vec<usize> {
        kinds_of(recording, kinds).into_iter().filter(|&k| recording.topics[k].count > 0).collect()
    };
    // A depth camera's images are Image topics named so (`/camera/depth/image_raw`,
    // `/camera/aligned_depth_to_color/image_raw`); the others are the camera's.
    let is_depth = |k: &usize| recording.topics[*k].name.contains("depth");
    let depth_candidates: Vec<usize> = non_empty(&[Image]).into_iter().filter(is_depth).collect();
    let depth =
        pick(recording, "depth camera", "--depth-topic", options.depth_topic.as_deref(), &[Image], depth_candidates)?;
    let lidar = pick(
        recording,
        "LIDAR",
        "--lidar-topic",
        options.lidar_topic.as_deref(),
        &[PointCloud2],
        non_empty(&[PointCloud2]),
    )?;
    // A LIDAR is the 3D sensor when there is one, unless a depth topic is named.
    let (lidar, range) = match (lidar, depth) {
        (_, Some(d)) if options.depth_topic.is_some() => (d, RangeSensor::DepthCamera),
        (Some(l), _) => (l, RangeSensor::Lidar),
        (None, Some(d)) => (d, RangeSensor::DepthCamera),
        (None, None) => {
            return Err(bag_error(
                recording,
                "no sensor_msgs/msg/PointCloud2 topic and no depth image topic: localization needs a 3D sensor",
            ));
        }
    };
    let colour: Vec<usize> =
        non_empty(&[Image, CompressedImage]).into_iter().filter(|k| !is_depth(k) && *k != lidar).collect();
    let image =
        pick(recording, "camera", "--image-topic", options.image_topic.as_deref(), &[Image, CompressedImage], colour)?;
    let infos = non_empty(&[CameraInfo]);
    let same_namespace = |topic: Option<usize>| infos_near(recording, &infos, topic);
    let camera_info = pick(
        recording,
        "camera_info",
        "--camera-info-topic",
        options.camera_info_topic.as_deref(),
        &[CameraInfo],
        same_namespace(image),
    )?;
    let depth_info = match range {
        RangeSensor::DepthCamera => {
            let info = pick(recording, "depth camera_info", "", None, &[CameraInfo], same_namespace(Some(lidar)))?;
            Some(info.ok_or_else(|| bag_error(recording, "the depth images have no sensor_msgs/msg/CameraInfo topic"))?)
        }
        RangeSensor::Lidar => None,
    };
    // Either may be missing: the previous motion then carries on (`SensorReplay`).
    let imu = pick(recording, "IMU", "--imu-topic", options.imu_topic.as_deref(), &[Imu], non_empty(&[Imu]))?;
    let odometry = pick(
        recording,
        "odometry",
        "--odom-topic",
        options.odom_topic.as_deref(),
        &[Odometry],
        non_empty(&[Odometry]),
    )?;
    // Ground truth is never guessed among odometry topics: by type, only
    // PoseStamped ones.
    let ground_truth = pick(
        recording,
        "ground truth",
        "--gt-topic",
        options.gt_topic.as_deref(),
        &POSE_KINDS,
        non_empty(&[PoseStamped]),
    )?;
    let by_name = |name: &str| recording.topic(name).filter(|&k| recording.topics[k].kind() == Some(TfMessage));
    let (tf_static, tf) = (by_name("/tf_static").or(by_name("tf_static")), by_name("/tf").or(by_name("tf")));
    let roles = Roles { lidar, range, depth_info, image, camera_info, imu, odometry, ground_truth, tf_static, tf };
    let notes = role_notes(recording, &roles);
    Ok((roles, notes))
}

/// The camera_info topics of `topic`'s namespace, when there are several
/// (all of them when none shares it).
fn infos_near(recording: &Recording, infos: &[usize], topic: Option<usize>) -> Vec<usize> {
    match topic {
        Some(i) if infos.len() > 1 => {
            let ns = |name: &str| name.rsplit_once('/').map_or(String::new(), |(a, _)| a.to_string());
            let image_ns = ns(&recording.topics[i].name);
            let matching: Vec<usize> =
                infos.iter().copied().filter(|&k| image_ns.starts_with(&ns(&recording.topics[k].name))).collect();
            if matching.is_empty() { infos.to_vec() } else { matching }
        }
        _ => infos.to_vec(),
    }
}

/// One line per role: the topic it takes, its type and message count.
fn role_notes(recording: &Recording, roles: &Roles) -> Vec<String> {
    let describe = |role: &str, k: Option<usize>| match k {
        Some(k) => {
            let t = &recording.topics[k];
            format!("{role:<12} {} ({}, {} messages)", t.name, t.type_name, t.count)
        }
        None => format!("{role:<12} none"),
    };
    let mut notes =
        vec![describe(if roles.range == RangeSensor::Lidar { "lidar" } else { "depth camera" }, Some(roles.lidar))];
    if roles.depth_info.is_some() {
        notes.push(describe("depth info", roles.depth_info));
    }
    for (role, topic) in [
        ("camera", roles.image),
        ("camera_info", roles.camera_info),
        ("imu", roles.imu),
        ("odometry", roles.odometry),
        ("ground truth", roles.ground_truth),
        ("tf_static", roles.tf_static),
    ] {
        notes.push(describe(role, topic));
    }
    notes
}

/// A scan or an image: its header stamp and its message index on its topic.
#[derive(Debug, Clone, Copy)]
struct Stamped {
    stamp: f64,
    index: u64,
}

pub struct BagSequence {
    pub recording: Recording,
    pub roles: Roles,
    pub calibration: Calibration,
    pub odometry: Vec<OdometrySample>,
    pub imu: Vec<ImuSample>,
    /// World from robot in the ground-truth topic's own frame (a run puts
    /// it in its world: `run::truth_in_run_frame`).
    pub ground_truth: Option<Trajectory>,
    /// What was chosen and why, for the user.
    pub notes: Vec<String>,
    scans: Vec<Stamped>,
    images: Vec<Stamped>,
    pairs: Vec<Option<usize>>,
    undistort: Option<Undistorter>,
    /// The depth camera's intrinsics, when it is the 3D sensor.
    depth_camera: Option<PinholeCamera>,
    depth: DepthOptions,
    tolerance_s: f64,
}

/// Everything the first pass collects.
#[derive(Default)]
struct FirstPass {
    tf: TfTree,
    camera_info: Option<camera_info::CameraInfo>,
    depth_info: Option<camera_info::CameraInfo>,
    lidar_frame: Option<String>,
    image_frame: Option<String>,
    imu_frame: Option<String>,
    scans: Vec<Stamped>,
    images: Vec<Stamped>,
    imu: Vec<geometry::ImuMessage>,
    odometry: Vec<geometry::OdometryMessage>,
    truth: Trajectory,
    dropped_duplicates: usize,
    /// Of those, the 3D sensor's.
    dropped_scans: usize,
}

/// Rejects a stamp older than the previous one on the same topic, and
/// tells whether it repeats it (then the message is skipped).
fn in_order(recording: &Recording, m: &RawMessage<'_>, previous: Option<f64>, stamp: f64) -> datasets::Result<bool> {
    match previous {
        Some(p) if stamp < p => Err(datasets::DataError::message(
            &recording.path,
            &recording.topics[m.topic].name,
            m.index,
            format!("the clock jumps back: header stamp {stamp:.9} s after {p:.9} s"),
        )),
        Some(p) => Ok(stamp > p),
        None => Ok(true),
    }
}

impl BagSequence {
    pub fn open(path: &Path, options: &BagOptions, sync: &SyncConfig) -> Result<Self> {
        sync.validate().map_err(|e| e.within("sync"))?;
        let recording = Recording::open(path)?;
        let (roles, mut notes) = find_roles(&recording, options)?;
        let pass = Self::first_pass(&recording, &roles)?;
        Self::check_scans(&recording, &roles, &pass)?;
        if pass.dropped_duplicates > 0 {
            notes
                .push(format!("skipped {} messages that repeat their topic's previous stamp", pass.dropped_duplicates));
        }
        notes.extend(pass.tf.conflicts().iter().map(|c| format!("tf_static    {c} (--calib sets one)")));
        let base = options.base_frame.clone().unwrap_or_else(|| "base_link".to_string());
        let (calibration, undistort) = Self::calibration(&recording, &roles, &pass, &base, options, &mut notes)?;
        let depth_camera = Self::depth_camera(&recording, &roles, &pass)?;
        let (imu, odometry) = Self::motion_logs(&recording, &pass, &base, options)?;
        let scan_times: Vec<f64> = pass.scans.iter().map(|s| s.stamp).collect();
        let mut images = pass.images.clone();
        images.sort_by(|a, b| a.stamp.total_cmp(&b.stamp));
        let image_times: Vec<f64> = images.iter().map(|s| s.stamp).collect();
        let pairs = nearest_within(&scan_times, &image_times, sync.image_tolerance_s);
        if roles.image.is_some() {
            let paired = pairs.iter().filter(|p| p.is_some()).count();
            notes.push(format!(
                "{paired} of {} scans have an image within {} s",
                pass.scans.len(),
                sync.image_tolerance_s
            ));
        }
        let ground_truth = (!pass.truth.is_empty()).then(|| pass.truth.clone());
        Ok(Self {
            recording,
            roles,
            calibration,
            odometry,
            imu,
            ground_truth,
            notes,
            scans: pass.scans,
            images,
            pairs,
            undistort,
            depth_camera,
            depth: options.depth.clone(),
            tolerance_s: sync.image_tolerance_s,
        })
    }

    /// Scans there must be, with their header stamps set: scans that mostly
    /// repeat a stamp (all 0: a driver that never set them) leave a few poses
    /// whose errors mean nothing.
    fn check_scans(recording: &Recording, roles: &Roles, pass: &FirstPass) -> Result<()> {
        if pass.scans.is_empty() {
            return Err(bag_error(recording, format!("topic {} has no messages", recording.topics[roles.lidar].name)));
        }
        if pass.dropped_scans >= pass.scans.len() {
            return Err(bag_error(
                recording,
                format!(
                    "{} of the {} messages of {} repeat the stamp before them (the first stamp: {:.6} s): \
                     the scans' header stamps are not set",
                    pass.dropped_scans,
                    pass.dropped_scans + pass.scans.len(),
                    recording.topics[roles.lidar].name,
                    pass.scans[0].stamp
                ),
            ));
        }
        Ok(())
    }

    /// A depth camera's pinhole, from its rectified camera_info.
    fn depth_camera(recording: &Recording, roles: &Roles, pass: &FirstPass) -> Result<Option<PinholeCamera>> {
        Ok(match (roles.range, &pass.depth_info) {
            (RangeSensor::Lidar, _) => None,
            (RangeSensor::DepthCamera, None) => {
                return Err(bag_error(recording, "the depth camera's camera_info topic has no messages"));
            }
            (RangeSensor::DepthCamera, Some(info)) => {
                // Points through a pinhole that the images do not follow would be bent.
                if !info.is_undistorted() {
                    return Err(bag_error(
                        recording,
                        format!("the depth camera_info has distortion {:?}: depth images must be rectified", info.d),
                    ));
                }
                let camera = info.raw_camera();
                camera.validate().map_err(|why| bag_error(recording, format!("depth camera_info: {why}")))?;
                Some(camera)
            }
        })
    }

    /// The IMU log turned into the robot's frame, and the odometry log.
    fn motion_logs(
        recording: &Recording,
        pass: &FirstPass,
        base: &str,
        options: &BagOptions,
    ) -> Result<(Vec<ImuSample>, Vec<OdometrySample>)> {
        let robot_from_imu = match &pass.imu_frame {
            Some(frame) if !frame.is_empty() && (options.calib.is_none() || !pass.tf.is_empty()) => {
                pass.tf.lookup(base, frame, false).or_else(|| pass.tf.lookup(base, frame, true)).ok_or_else(|| {
                    bag_error(
                        recording,
                        format!("no transform from the IMU frame `{frame}` to `{base}` in /tf_static or /tf"),
                    )
                })?
            }
            _ => Pose3::identity(),
        };
        let imu: Vec<ImuSample> = pass
            .imu
            .iter()
            .map(|m| ImuSample {
                timestamp: m.header.stamp_s(),
                accel: (robot_from_imu.rotation * m.linear_acceleration).into(),
                gyro: (robot_from_imu.rotation * m.angular_velocity).into(),
            })
            .collect();
        let odometry: Vec<OdometrySample> = pass
            .odometry
            .iter()
            .map(|m| {
                let (_, _, yaw) = m.pose.rotation.euler_angles();
                let t = m.pose.translation.vector;
                OdometrySample { timestamp: m.header.stamp_s(), x: t.x, y: t.y, yaw, v: m.linear.x, omega: m.angular.z }
            })
            .collect();
        Ok((imu, odometry))
    }

    fn first_pass(recording: &Recording, roles: &Roles) -> Result<FirstPass> {
        let mut pass = FirstPass::default();
        let wanted: Vec<usize> =
            [Some(roles.lidar), roles.image, roles.camera_info, roles.depth_info, roles.imu, roles.odometry]
                .into_iter()
                .chain([roles.ground_truth, roles.tf_static, roles.tf])
                .flatten()
                .collect();
        let truth_kind = roles.ground_truth.and_then(|k| recording.topics[k].kind());
        recording.read(&wanted, &mut |m| {
            let header = || recording.decode(&m, |r| r.header());
            if m.topic == roles.lidar {
                let h = header()?;
                if in_order(recording, &m, pass.scans.last().map(|s| s.stamp), h.stamp_s())? {
                    pass.scans.push(Stamped { stamp: h.stamp_s(), index: m.index });
                } else {
                    pass.dropped_duplicates += 1;
                    pass.dropped_scans += 1;
                }
                pass.lidar_frame.get_or_insert(h.frame_id);
            } else if Some(m.topic) == roles.image {
                let h = header()?;
                pass.images.push(Stamped { stamp: h.stamp_s(), index: m.index });
                pass.image_frame.get_or_insert(h.frame_id);
            } else if Some(m.topic) == roles.depth_info {
                if pass.depth_info.is_none() {
                    pass.depth_info = Some(recording.decode(&m, camera_info::camera_info)?);
                }
            } else if Some(m.topic) == roles.camera_info {
                if pass.camera_info.is_none() {
                    pass.camera_info = Some(recording.decode(&m, camera_info::camera_info)?);
                }
            } else if Some(m.topic) == roles.imu {
                let imu = recording.decode(&m, geometry::imu)?;
                if in_order(recording, &m, pass.imu.last().map(|s| s.header.stamp_s()), imu.header.stamp_s())? {
                    pass.imu_frame.get_or_insert(imu.header.frame_id.clone());
                    pass.imu.push(imu);
                } else {
                    pass.dropped_duplicates += 1;
                }
            } else if Some(m.topic) == roles.odometry {
                let odom = recording.decode(&m, geometry::odometry)?;
                if in_order(recording, &m, pass.odometry.last().map(|s| s.header.stamp_s()), odom.header.stamp_s())? {
                    pass.odometry.push(odom);
                } else {
                    pass.dropped_duplicates += 1;
                }
            } else if Some(m.topic) == roles.ground_truth {
                let pose = recording.decode(&m, |r| stamped_pose(truth_kind.expect("a pose type"), r))?;
                let stamp = pose.header.stamp_s();
                if in_order(recording, &m, pass.truth.stamps.last().copied(), stamp)? {
                    pass.truth.push(stamp, pose.pose);
                } else {
                    pass.dropped_duplicates += 1;
                }
            } else if Some(m.topic) == roles.tf_static || Some(m.topic) == roles.tf {
                let is_static = Some(m.topic) == roles.tf_static;
                for transform in recording.decode(&m, geometry::tf_message)? {
                    pass.tf.add(&transform, is_static);
                }
            }
            Ok(())
        })?;
        Ok(pass)
    }

    fn calibration(
        recording: &Recording,
        roles: &Roles,
        pass: &FirstPass,
        base: &str,
        options: &BagOptions,
        notes: &mut Vec<String>,
    ) -> Result<(Calibration, Option<Undistorter>)> {
        if let Some(path) = &options.calib {
            notes.push(format!("calibration  {} (replaces the recording's)", path.display()));
            return Ok((read_calibration(path)?, None));
        }
        if roles.tf_static.is_none() {
            return Err(bag_error(
                recording,
                "no /tf_static topic and no --calib: the LIDAR's and the camera's place on the robot are unknown",
            ));
        }
        let frames = || pass.tf.frames().into_iter().collect::<Vec<_>>().join(", ");
        let lookup = |target: &str, source: &str, what: &str| -> Result<Pose3> {
            pass.tf.lookup(target, source, false).or_else(|| pass.tf.lookup(target, source, true)).ok_or_else(|| {
                bag_error(
                    recording,
                    format!("no transform from {what} `{source}` to `{target}` (frames: {})", frames()),
                )
            })
        };
        let lidar_frame = pass.lidar_frame.clone().unwrap_or_default();
        let robot_from_lidar = lookup(base, &lidar_frame, "the LIDAR frame")?;
        let (camera, camera_from_lidar, undistort) = match roles.image {
            None => (PinholeCamera::kinect(), Pose3::identity(), None),
            Some(image_topic) => {
                let info = pass.camera_info.as_ref().ok_or_else(|| {
                    bag_error(
                        recording,
                        "the camera has no sensor_msgs/msg/CameraInfo topic: pass --calib with its intrinsics",
                    )
                })?;
                let frame = pass.image_frame.clone().unwrap_or_else(|| info.header.frame_id.clone());
                let camera_from_lidar = lookup(&frame, &lidar_frame, "the LIDAR frame")?;
                let rectified = recording.topics[image_topic].name.contains("rect");
                let (camera, undistort) = if rectified {
                    notes.push("camera       rectified images: the pinhole of camera_info's P".into());
                    (info.rectified_camera(), None)
                } else if info.is_undistorted() {
                    (info.raw_camera(), None)
                } else {
                    let u = Undistorter::new(&info.raw_camera(), &info.distortion_model, &info.d)
                        .map_err(|why| bag_error(recording, format!("camera_info: {why}")))?;
                    notes.push(format!("camera       undistorted ({}, D = {:?})", info.distortion_model, info.d));
                    (info.raw_camera(), Some(u))
                };
                camera.validate().map_err(|why| bag_error(recording, format!("camera_info: {why}")))?;
                (camera, camera_from_lidar, undistort)
            }
        };
        notes.push(format!(
            "frames       robot `{base}`, LIDAR `{lidar_frame}`, camera `{}`",
            pass.image_frame.as_deref().unwrap_or("-")
        ));
        // A depth camera's "LIDAR" frame is its body frame (x forward, z up),
        // in which its points are given; its images are in the optical frame.
        let (camera_from_lidar, robot_from_lidar) = match roles.range {
            RangeSensor::DepthCamera => {
                (camera_from_lidar * optical_from_body(), robot_from_lidar * optical_from_body())
            }
            RangeSensor::Lidar => (camera_from_lidar, robot_from_lidar),
        };
        Ok((Calibration { camera, camera_from_lidar, robot_from_lidar }, undistort))
    }

    /// A depth image message as a scan in the depth camera's body frame.
    fn depth_cloud(
        &self,
        m: &RawMessage<'_>,
        camera: &PinholeCamera,
    ) -> std::result::Result<datasets::io::formats::PointCloud, FrameFault> {
        let depth =
            self.recording.decode(m, image::depth_image).map_err(|e| FrameFault::Unreadable(e.to_string()))?.depth;
        if (depth.width, depth.height) != (camera.width, camera.height) {
            return Err(FrameFault::WrongSize {
                source: format!("topic {}, message {}", self.recording.topics[m.topic].name, m.index),
                what: "depth image",
                size: [depth.width, depth.height],
                reference: "its camera_info says",
                expected: [camera.width, camera.height],
            });
        }
        Ok(crate::input::rgbd_sequence::depth_scan(&depth, camera, &self.depth))
    }

    fn decode_image(&self, m: &RawMessage<'_>) -> std::result::Result<::image::DynamicImage, FrameFault> {
        let kind = self.recording.topics[m.topic].kind();
        let decoded = match kind {
            Some(MessageKind::CompressedImage) => self.recording.decode(m, image::compressed_image),
            _ => self.recording.decode(m, image::image),
        }
        .map_err(|e| FrameFault::Unreadable(e.to_string()))?;
        let camera = &self.calibration.camera;
        let im = match &self.undistort {
            Some(u) => u.apply(&decoded.image).map_err(|e| {
                FrameFault::Unreadable(format!(
                    "topic {} message {}: {e}",
                    self.recording.topics[m.topic].name, m.index
                ))
            })?,
            None => decoded.image,
        };
        if im.width() != camera.width || im.height() != camera.height {
            return Err(FrameFault::WrongSize {
                source: format!("topic {}, message {}", self.recording.topics[m.topic].name, m.index),
                what: "image",
                size: [im.width(), im.height()],
                reference: "the camera is",
                expected: [camera.width, camera.height],
            });
        }
        Ok(im)
    }
}

impl SensorSequence for BagSequence {
    fn calibration(&self) -> &Calibration {
        &self.calibration
    }
    fn odometry(&self) -> &[OdometrySample] {
        &self.odometry
    }
    fn imu(&self) -> &[ImuSample] {
        &self.imu
    }
    fn ground_truth(&self) -> Option<&Trajectory> {
        self.ground_truth.as_ref()
    }
    fn world_description(&self) -> Option<PathBuf> {
        None
    }
    fn frame_stamps(&self) -> Vec<f64> {
        self.scans.iter().map(|s| s.stamp).collect()
    }
    fn range_sensor(&self) -> RangeSensor {
        self.roles.range
    }
    fn log_source(&self, log: MotionLog) -> String {
        let topic = match log {
            MotionLog::Odometry => self.roles.odometry,
            MotionLog::Imu => self.roles.imu,
        };
        match topic {
            Some(t) => format!("{}: topic {}", self.recording.path.display(), self.recording.topics[t].name),
            None => log.to_string(),
        }
    }

    /// One pass over the LIDAR and camera topics in file order: a scan waits
    /// until its image has come by (a camera may lag its LIDAR), and an
    /// image is kept only until the last scan that takes it.
    fn for_each_frame(&self, visit: &mut dyn FnMut(FrameInput) -> Result<()>) -> Result<()> {
        let scan_of: HashMap<u64, usize> = self.scans.iter().enumerate().map(|(k, s)| (s.index, k)).collect();
        let mut image_users: HashMap<u64, usize> = HashMap::new();
        for j in self.pairs.iter().flatten() {
            *image_users.entry(self.images[*j].index).or_default() += 1;
        }
        let image_slot: HashMap<u64, usize> = self.images.iter().enumerate().map(|(j, s)| (s.index, j)).collect();
        let mut held: HashMap<usize, std::result::Result<::image::DynamicImage, FrameFault>> = HashMap::new();
        let mut pending: VecDeque<(usize, std::result::Result<datasets::io::formats::PointCloud, FrameFault>)> =
            VecDeque::new();
        let wanted: Vec<usize> = [Some(self.roles.lidar), self.roles.image].into_iter().flatten().collect();
        let mut flush = |pending: &mut VecDeque<_>,
                         held: &mut HashMap<usize, _>,
                         image_users: &mut HashMap<u64, usize>,
                         all: bool|
         -> Result<()> {
            while let Some((k, _)) = pending.front() {
                let k: usize = *k;
                let image = match self.pairs[k] {
                    None => Err(FrameFault::no_image_near(self.tolerance_s, self.scans[k].stamp)),
                    Some(j) if !held.contains_key(&j) => {
                        if !all {
                            // Its image comes later in the file: wait for it.
                            return Ok(());
                        }
                        Err(FrameFault::ImageNeverCame { message: self.images[j].index, stamp: self.scans[k].stamp })
                    }
                    Some(j) => {
                        let users = image_users.entry(self.images[j].index).or_default();
                        *users = users.saturating_sub(1);
                        // The last scan that takes an image takes it over; earlier ones copy it.
                        let image: std::result::Result<::image::DynamicImage, FrameFault> =
                            if *users == 0 { held.remove(&j).expect("held") } else { held[&j].clone() };
                        Ok(FrameImage {
                            stamp: self.images[j].stamp,
                            name: datasets::io::formats::stamped_files::stamp_name(self.images[j].stamp),
                            image,
                        })
                    }
                };
                let (_, cloud) = pending.pop_front().expect("front exists");
                visit(FrameInput { stamp: self.scans[k].stamp, cloud, image, edges: Vec::new() })?;
            }
            Ok(())
        };
        // The visitor's own error stops the read and comes back as it was.
        let mut failure: Option<LocalizeError> = None;
        let outcome = self.recording.read(&wanted, &mut |m| {
            if m.topic == self.roles.lidar {
                let Some(&k) = scan_of.get(&m.index) else { return Ok(()) };
                let cloud = match &self.depth_camera {
                    Some(camera) => self.depth_cloud(&m, camera),
                    None => self
                        .recording
                        .decode(&m, point_cloud::point_cloud2)
                        .map(|c| c.cloud)
                        .map_err(|e| FrameFault::Unreadable(e.to_string())),
                };
                pending.push_back((k, cloud));
            } else if let Some(&j) = image_slot.get(&m.index)
                && image_users.get(&m.index).is_some_and(|&n| n > 0)
            {
                held.insert(j, self.decode_image(&m));
            }
            flush(&mut pending, &mut held, &mut image_users, false).map_err(|e| {
                failure = Some(e);
                datasets::DataError::invalid(&self.recording.path, "stopped")
            })
        });
        if let Some(e) = failure {
            return Err(e);
        }
        outcome?;
        flush(&mut pending, &mut held, &mut image_users, true)?;
        Ok(())
    }
}
