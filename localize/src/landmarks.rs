//! Corner landmarks: fused corners clustered over frames in the world frame.
//! An observation joins the nearest landmark within the gate, or starts a new
//! one; a landmark is trusted for pose estimation once seen `min_observations` times.

use datasets::math::Vec3;
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LandmarkConfig {
    pub gate_m: f64,
    pub min_observations: u32,
}

impl Default for LandmarkConfig {
    fn default() -> Self {
        Self { gate_m: 0.4, min_observations: 2 }
    }
}

#[derive(Debug, Clone, PartialEq)]
pub struct Landmark {
    /// Mean of the observations.
    pub position: Vec3,
    pub observations: u32,
    sum: Vec3,
}

#[derive(Debug, Clone, Default)]
pub struct LandmarkMap {
    pub config: LandmarkConfig,
    pub landmarks: Vec<Landmark>,
}

impl LandmarkMap {
    pub fn new(config: LandmarkConfig) -> Self {
        Self { config, landmarks: Vec::new() }
    }

    /// For each world point, the nearest landmark within the gate; a landmark
    /// goes to at most one point (the closest).
    pub fn associate(&self, points: &[Vec3]) -> Vec<Option<usize>> {
        let gate = self.config.gate_m;
        let mut claims: Vec<(f64, usize, usize)> = Vec::new();
        for (i, p) in points.iter().enumerate() {
            for (k, l) in self.landmarks.iter().enumerate() {
                let d = (l.position - p).norm();
                if d < gate {
                    claims.push((d, i, k));
                }
            }
        }
        claims.sort_by(|a, b| a.0.total_cmp(&b.0));
        let mut out = vec![None; points.len()];
        let mut taken = vec![false; self.landmarks.len()];
        for (_, i, k) in claims {
            if out[i].is_none() && !taken[k] {
                out[i] = Some(k);
                taken[k] = true;
            }
        }
        out
    }

    pub fn is_trusted(&self, k: usize) -> bool {
        self.landmarks[k].observations >= self.config.min_observations
    }

    /// Adds observations: to their landmark, or as new landmarks.
    pub fn observe(&mut self, points: &[Vec3], association: &[Option<usize>]) {
        for (p, a) in points.iter().zip(association) {
            match a {
                Some(k) => {
                    let l = &mut self.landmarks[*k];
                    l.sum += p;
                    l.observations += 1;
                    l.position = l.sum / l.observations as f64;
                }
                None => self.landmarks.push(Landmark { position: *p, observations: 1, sum: *p }),
            }
        }
    }
}
