//! Geometry types used across the project, set once. Frames are named in
//! variable names (`world_from_robot`, `camera_from_lidar`); units are metres
//! and radians.

pub type Vec3 = nalgebra::Vector3<f64>;
pub type Point3 = nalgebra::Point3<f64>;
pub type Pose3 = nalgebra::Isometry3<f64>;
pub type Rot3 = nalgebra::UnitQuaternion<f64>;
pub type Mat3 = nalgebra::Matrix3<f64>;
pub type Mat4 = nalgebra::Matrix4<f64>;

/// A 4x4 homogeneous matrix as rows, the form used in JSON files.
pub type RowsMat4 = [[f64; 4]; 4];

/// The median of `values` (the upper one of an even count); None when empty.
pub fn median(mut values: Vec<f64>) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    let middle = values.len() / 2;
    Some(*values.select_nth_unstable_by(middle, f64::total_cmp).1)
}

pub fn pose_to_rows(pose: &Pose3) -> RowsMat4 {
    let m = pose.to_homogeneous();
    std::array::from_fn(|r| std::array::from_fn(|c| m[(r, c)]))
}

/// Converts a 4x4 row-major rigid transform to a pose; `None` when the matrix
/// is not finite, its last row is not (0 0 0 1) or its rotation block is not
/// orthonormal with determinant +1 (to 1e-4).
pub fn pose_from_rows(rows: &RowsMat4) -> Option<Pose3> {
    if rows.iter().flatten().any(|v| !v.is_finite()) {
        return None;
    }
    let last = rows[3];
    if last[0].abs() > 1e-9 || last[1].abs() > 1e-9 || last[2].abs() > 1e-9 || (last[3] - 1.0).abs() > 1e-9 {
        return None;
    }
    let r = Mat3::from_fn(|i, j| rows[i][j]);
    let t = Vec3::new(rows[0][3], rows[1][3], rows[2][3]);
    rotation_from_matrix(&r).map(|q| Pose3::from_parts(t.into(), q))
}

/// A rotation from a 3x3 matrix that should be a rotation (orthonormal,
/// determinant +1, to 1e-4); re-orthonormalised so that files written with
/// few digits still load.
pub fn rotation_from_matrix(r: &Mat3) -> Option<Rot3> {
    let should_be_identity = r.transpose() * r - Mat3::identity();
    if should_be_identity.abs().max() > 1e-4 || (r.determinant() - 1.0).abs() > 1e-4 {
        return None;
    }
    let rot = nalgebra::Rotation3::from_matrix_eps(r, 1e-12, 100, nalgebra::Rotation3::identity());
    Some(Rot3::from_rotation_matrix(&rot))
}
