//! The filter's attitude as ZYX Euler angles (roll, pitch, yaw; world from
//! robot): the rotation they stand for and the wrapping of angle sums.

use datasets::math::Rot3;

/// The rotation of roll, pitch and yaw.
pub fn rotation(roll: f64, pitch: f64, yaw: f64) -> Rot3 {
    Rot3::from_euler_angles(roll, pitch, yaw)
}

/// Wraps an angle to (-pi, pi].
pub fn wrap(a: f64) -> f64 {
    let w = a.rem_euclid(std::f64::consts::TAU);
    if w > std::f64::consts::PI { w - std::f64::consts::TAU } else { w }
}
