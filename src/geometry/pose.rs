//! SE(3) poses. A sequence stores each frame's camera-to-world pose `T_wc`: `X_w = T_wc X_c`.
//! The transform that takes reference-camera points into frame `n`'s camera is
//! `T_nr = T_wn⁻¹ T_wr` ([`relative_pose`]).

use nalgebra::{Isometry3, Matrix3, Matrix4, Quaternion, Rotation3, Translation3, UnitQuaternion, Vector3};

/// A rigid transform (rotation + translation in metres).
pub type Pose = Isometry3<f64>;

/// Largest `‖RᵀR - I‖_max` (and `|det R - 1|`) accepted for a rotation read from a file. Files store
/// 6-18 significant digits; HoloLens poses are orthonormal to 1e-5.
pub const ROTATION_TOLERANCE: f64 = 1e-3;

/// Largest `| |q| - 1 |` accepted for a quaternion read from a file before it is normalised.
pub const QUATERNION_NORM_TOLERANCE: f64 = 1e-2;

/// `T_nr = T_wn⁻¹ T_wr`: maps points from the reference camera `r` into camera `n`.
pub fn relative_pose(t_wr: &Pose, t_wn: &Pose) -> Pose {
    t_wn.inverse() * t_wr
}

/// A pose from a 4x4 matrix `[R t; 0 0 0 1]`.
///
/// # Errors
/// A message saying what is wrong: a non-finite entry, a last row other than `0 0 0 1`, or a
/// rotation that is not orthonormal with determinant +1 within [`ROTATION_TOLERANCE`]. The nearest
/// rotation (nalgebra's `Rotation3::from_matrix`) is used when the check passes.
pub fn pose_from_matrix(m: &Matrix4<f64>) -> Result<Pose, String> {
    if m.iter().any(|v| !v.is_finite()) {
        return Err("pose matrix has a non-finite entry".into());
    }
    let last = m.row(3);
    if (last[0].abs() + last[1].abs() + last[2].abs() + (last[3] - 1.0).abs()) > 1e-6 {
        return Err(format!(
            "pose matrix last row is [{} {} {} {}], expected [0 0 0 1]",
            last[0], last[1], last[2], last[3]
        ));
    }
    let r: Matrix3<f64> = m.fixed_view::<3, 3>(0, 0).into_owned();
    let ortho = (r.transpose() * r - Matrix3::identity()).abs().max();
    let det = r.determinant();
    if ortho > ROTATION_TOLERANCE || (det - 1.0).abs() > ROTATION_TOLERANCE {
        return Err(format!(
            "rotation is not orthonormal: max |RᵀR - I| = {ortho:.2e}, det R = {det:.6} (tolerance {ROTATION_TOLERANCE:e})"
        ));
    }
    let rot = Rotation3::from_matrix(&r);
    let t = Vector3::new(m[(0, 3)], m[(1, 3)], m[(2, 3)]);
    Ok(Isometry3::from_parts(Translation3::from(t), UnitQuaternion::from_rotation_matrix(&rot)))
}

/// The 4x4 matrix of a pose.
pub fn pose_to_matrix(p: &Pose) -> Matrix4<f64> {
    p.to_homogeneous()
}

/// A pose from a TUM line's `tx ty tz qx qy qz qw` (Hamilton quaternion, scalar last in the file).
///
/// # Errors
/// A message if a value is not finite or `|q|` differs from 1 by more than
/// [`QUATERNION_NORM_TOLERANCE`].
pub fn pose_from_tum(t: [f64; 3], q_xyzw: [f64; 4]) -> Result<Pose, String> {
    if t.iter().chain(q_xyzw.iter()).any(|v| !v.is_finite()) {
        return Err("pose has a non-finite value".into());
    }
    let q = Quaternion::new(q_xyzw[3], q_xyzw[0], q_xyzw[1], q_xyzw[2]);
    let n = q.norm();
    if (n - 1.0).abs() > QUATERNION_NORM_TOLERANCE {
        return Err(format!("quaternion norm is {n:.6}, expected 1 (tolerance {QUATERNION_NORM_TOLERANCE})"));
    }
    Ok(Isometry3::from_parts(Translation3::new(t[0], t[1], t[2]), UnitQuaternion::from_quaternion(q)))
}

/// A camera-to-world pose whose camera axes are OpenGL's (x right, y up, looking along -z: ARKit,
/// Record3D, nerfstudio) in ours (x right, y down, looking along +z): the camera's y and z axes are
/// negated, `T_wc = T_wc_gl diag(1, -1, -1, 1)`, a half turn about the camera's x axis (SPEC.md §2.3).
pub fn pose_from_opengl(t_wc_gl: &Pose) -> Pose {
    // The half turn about x as an exact quaternion (w = 0, x = 1).
    t_wc_gl * UnitQuaternion::new_unchecked(Quaternion::new(0.0, 1.0, 0.0, 0.0))
}

/// Interpolate between two poses: translation linearly, rotation by slerp, `s ∈ [0, 1]`.
pub fn slerp_pose(a: &Pose, b: &Pose, s: f64) -> Pose {
    let t = a.translation.vector.lerp(&b.translation.vector, s);
    let r = a.rotation.slerp(&b.rotation, s);
    Isometry3::from_parts(Translation3::from(t), r)
}
