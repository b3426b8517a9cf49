//! Every setting of localization, one section per stage; `localize run
//! --config FILE` reads it as JSON (missing fields keep their defaults) and
//! the run folder keeps the resolved copy.

use serde::{Deserialize, Serialize};

use crate::corners::CornerConfig;
use crate::ekf::EkfConfig;
use crate::fusion::FusionConfig;
use crate::landmarks::LandmarkConfig;
use crate::normals::NormalConfig;
use crate::plane_landmarks::PlaneLandmarkConfig;
use crate::planes::PlaneConfig;
use crate::pose::PoseConfig;
use crate::sequence::SyncConfig;
use crate::voxel::VoxelConfig;

#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LocalizeConfig {
    pub voxel: VoxelConfig,
    pub normals: NormalConfig,
    pub planes: PlaneConfig,
    pub corners: CornerConfig,
    pub fusion: FusionConfig,
    pub landmarks: LandmarkConfig,
    pub plane_landmarks: PlaneLandmarkConfig,
    pub pose: PoseConfig,
    pub ekf: EkfConfig,
    pub sync: SyncConfig,
}
