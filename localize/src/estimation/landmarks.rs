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
    /// Trusted only while the observations agree to this RMS spread.
    pub max_spread_m: f64,
    /// Observations after this many no longer move the landmark, so that the
    /// map does not follow the pose it corrects.
    pub max_observations: u32,
}

impl Default for LandmarkConfig {
    fn default() -> Self {
        Self { gate_m: 0.4, min_observations: 2, max_spread_m: 0.05, max_observations: 20 }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Landmark {
    /// Mean of the observations.
    pub position: Vec3,
    pub observations: u32,
    sum: Vec3,
    square_sum: f64,
    /// Observations averaged into the position (at most `max_observations`).
    used: u32,
}

impl Landmark {
    /// Whether its numbers can be averaged on: finite, and at least one
    /// observation averaged in, no more than it was seen (a map file may say
    /// otherwise).
    pub fn is_valid(&self) -> bool {
        let finite = |v: &Vec3| v.iter().all(|x| x.is_finite());
        finite(&self.position)
            && finite(&self.sum)
            && self.square_sum.is_finite()
            && self.square_sum >= 0.0
            && (1..=self.observations).contains(&self.used)
    }

    /// RMS distance of the observations from their mean.
    pub fn spread_m(&self) -> f64 {
        let n = self.used as f64;
        (self.square_sum / n - self.position.norm_squared()).max(0.0).sqrt()
    }
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
        let l = &self.landmarks[k];
        l.observations >= self.config.min_observations && l.spread_m() <= self.config.max_spread_m
    }

    /// Adds observations: to their landmark, or as new landmarks.
    pub fn observe(&mut self, points: &[Vec3], association: &[Option<usize>]) {
        for (p, a) in points.iter().zip(association) {
            match a {
                Some(k) => {
                    let l = &mut self.landmarks[*k];
                    l.observations += 1;
                    if l.used < self.config.max_observations {
                        l.used += 1;
                        l.sum += p;
                        l.square_sum += p.norm_squared();
                        l.position = l.sum / l.used as f64;
                    }
                }
                None => self.landmarks.push(Landmark {
                    position: *p,
                    observations: 1,
                    sum: *p,
                    square_sum: p.norm_squared(),
                    used: 1,
                }),
            }
        }
    }
}
