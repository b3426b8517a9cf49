//! Similarity transforms and the least-squares fit of one point set onto
//! another: the alignment behind evo's `-a`/`-as` and the pose solver's
//! closed-form start.

use datasets::math::{Mat3, Vec3};

/// A similarity transform y = scale * rotation * x + translation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Similarity {
    pub rotation: Mat3,
    pub translation: Vec3,
    pub scale: f64,
}

impl Similarity {
    pub fn identity() -> Self {
        Self { rotation: Mat3::identity(), translation: Vec3::zeros(), scale: 1.0 }
    }
    pub fn apply(&self, x: &Vec3) -> Vec3 {
        self.scale * (self.rotation * x) + self.translation
    }
}

/// Umeyama (1991): the similarity that maps `from` onto `to` in the least
/// squares sense; with `with_scale` false the scale is fixed at 1. `None`
/// when fewer than 3 points or all points coincide.
pub fn umeyama(from: &[Vec3], to: &[Vec3], with_scale: bool) -> Option<Similarity> {
    let n = from.len();
    if n < 3 || to.len() != n {
        return None;
    }
    let mean = |v: &[Vec3]| v.iter().fold(Vec3::zeros(), |a, b| a + b) / n as f64;
    let (mean_from, mean_to) = (mean(from), mean(to));
    let mut covariance = Mat3::zeros();
    let mut variance_from = 0.0;
    for (x, y) in from.iter().zip(to) {
        let (dx, dy) = (x - mean_from, y - mean_to);
        covariance += dy * dx.transpose();
        variance_from += dx.norm_squared();
    }
    covariance /= n as f64;
    variance_from /= n as f64;
    if variance_from < 1e-18 {
        return None;
    }
    let svd = covariance.svd(true, true);
    let (u, v_t) = (svd.u?, svd.v_t?);
    // Flip the weakest axis when the best orthogonal matrix would be a reflection.
    let mut s = Vec3::new(1.0, 1.0, 1.0);
    if u.determinant() * v_t.determinant() < 0.0 {
        s[2] = -1.0;
    }
    let rotation = u * Mat3::from_diagonal(&s) * v_t;
    let scale = if with_scale { svd.singular_values.dot(&s) / variance_from } else { 1.0 };
    let translation = mean_to - scale * (rotation * mean_from);
    Some(Similarity { rotation, translation, scale })
}
