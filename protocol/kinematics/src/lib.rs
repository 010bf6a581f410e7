//! Homogeneous transformation matrices (HTMs) for machine kinematics.
//!
//! Conventions, used by every model built on this crate:
//! - An [`Htm`] maps coordinates of a child frame into its parent frame:
//!   `p_parent = T * p_child` (column vectors, homogeneous coordinate 1 for points and 0
//!   for directions). Chains compose left to right from the reference outwards:
//!   `T_ref_tool = T_ref_a * T_a_b * T_b_tool`.
//! - Rotations are right-handed, angles in radians, positive counter-clockwise when
//!   looking from the positive axis towards the origin.
//! - Lengths are in whatever unit the caller uses consistently (the machine models use mm).
//!
//! Worked example: a point 10 mm along X of a frame turned +90° about Z and moved
//! 5 mm along Y: `translation(0, 5, 0) * rot_z(π/2)` maps (10, 0, 0) to (0, 15, 0).

use nalgebra::{Matrix4, Vector3, Vector4};

/// A 4 x 4 homogeneous transformation (child frame -> parent frame).
pub type Htm = Matrix4<f64>;

/// Pure translation by (x, y, z).
pub fn translation(x: f64, y: f64, z: f64) -> Htm {
    let mut t = Htm::identity();
    t[(0, 3)] = x;
    t[(1, 3)] = y;
    t[(2, 3)] = z;
    t
}

/// Rotation by `angle` radians about X.
pub fn rot_x(angle: f64) -> Htm {
    let (s, c) = angle.sin_cos();
    Htm::new(
        1.0, 0.0, 0.0, 0.0, //
        0.0, c, -s, 0.0, //
        0.0, s, c, 0.0, //
        0.0, 0.0, 0.0, 1.0,
    )
}

/// Rotation by `angle` radians about Y.
pub fn rot_y(angle: f64) -> Htm {
    let (s, c) = angle.sin_cos();
    Htm::new(
        c, 0.0, s, 0.0, //
        0.0, 1.0, 0.0, 0.0, //
        -s, 0.0, c, 0.0, //
        0.0, 0.0, 0.0, 1.0,
    )
}

/// Rotation by `angle` radians about Z.
pub fn rot_z(angle: f64) -> Htm {
    let (s, c) = angle.sin_cos();
    Htm::new(
        c, -s, 0.0, 0.0, //
        s, c, 0.0, 0.0, //
        0.0, 0.0, 1.0, 0.0, //
        0.0, 0.0, 0.0, 1.0,
    )
}

/// The first-order (small-angle) error matrix of one axis or location, as in SPEC D:
/// translations `(dx, dy, dz)` and rotations `(ex, ey, ez)` about X, Y, Z (radians),
/// products of errors dropped:
///
/// ```text
/// [ 1    -ez   ey   dx ]
/// [ ez    1   -ex   dy ]
/// [ -ey   ex   1    dz ]
/// [ 0     0    0    1  ]
/// ```
///
/// It is not exactly orthonormal; [`exact_error`] is the rigid transform with the same
/// first-order terms, for models that compare exact and first-order results.
pub fn small_angle_error(dx: f64, dy: f64, dz: f64, ex: f64, ey: f64, ez: f64) -> Htm {
    Htm::new(
        1.0, -ez, ey, dx, //
        ez, 1.0, -ex, dy, //
        -ey, ex, 1.0, dz, //
        0.0, 0.0, 0.0, 1.0,
    )
}

/// The rigid transform `translation(dx, dy, dz) * rot_z(ez) * rot_y(ey) * rot_x(ex)`:
/// equal to [`small_angle_error`] to first order in the errors.
pub fn exact_error(dx: f64, dy: f64, dz: f64, ex: f64, ey: f64, ez: f64) -> Htm {
    translation(dx, dy, dz) * rot_z(ez) * rot_y(ey) * rot_x(ex)
}

/// The origin of the child frame, in the parent frame.
pub fn position(t: &Htm) -> Vector3<f64> {
    Vector3::new(t[(0, 3)], t[(1, 3)], t[(2, 3)])
}

/// The child frame's Z axis (a tool's direction), in the parent frame.
pub fn z_direction(t: &Htm) -> Vector3<f64> {
    Vector3::new(t[(0, 2)], t[(1, 2)], t[(2, 2)])
}

/// A point given in the child frame, in the parent frame.
pub fn transform_point(t: &Htm, p: &Vector3<f64>) -> Vector3<f64> {
    let v = t * Vector4::new(p.x, p.y, p.z, 1.0);
    Vector3::new(v.x, v.y, v.z)
}

/// A direction given in the child frame, in the parent frame (no translation).
pub fn transform_direction(t: &Htm, d: &Vector3<f64>) -> Vector3<f64> {
    let v = t * Vector4::new(d.x, d.y, d.z, 0.0);
    Vector3::new(v.x, v.y, v.z)
}

/// The inverse of a rigid transform (rotation part orthonormal): `[Rᵀ, -Rᵀ p]`, exact and
/// cheaper than a general 4 x 4 inverse. Not for [`small_angle_error`] matrices, which
/// are not orthonormal; use `try_inverse` for those.
pub fn rigid_inverse(t: &Htm) -> Htm {
    let r = t.fixed_view::<3, 3>(0, 0).transpose();
    let p = -(r * position(t));
    let mut inv = Htm::identity();
    inv.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
    inv[(0, 3)] = p.x;
    inv[(1, 3)] = p.y;
    inv[(2, 3)] = p.z;
    inv
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::FRAC_PI_2;

    fn close(a: &Vector3<f64>, b: &Vector3<f64>, tol: f64) -> bool {
        (a - b).norm() <= tol
    }

    #[test]
    fn worked_example_of_the_module_docs() {
        let t = translation(0.0, 5.0, 0.0) * rot_z(FRAC_PI_2);
        let p = transform_point(&t, &Vector3::new(10.0, 0.0, 0.0));
        assert!(close(&p, &Vector3::new(0.0, 15.0, 0.0), 1e-12), "{p}");
    }

    #[test]
    fn rotations_are_right_handed() {
        // +90° about X takes Y to Z; about Y takes Z to X; about Z takes X to Y.
        let y = Vector3::y();
        let z = Vector3::z();
        let x = Vector3::x();
        assert!(close(
            &transform_direction(&rot_x(FRAC_PI_2), &y),
            &z,
            1e-12
        ));
        assert!(close(
            &transform_direction(&rot_y(FRAC_PI_2), &z),
            &x,
            1e-12
        ));
        assert!(close(
            &transform_direction(&rot_z(FRAC_PI_2), &x),
            &y,
            1e-12
        ));
    }

    #[test]
    fn small_angle_error_agrees_with_the_exact_rigid_error_to_first_order() {
        let (ex, ey, ez) = (20e-6, -35e-6, 12e-6);
        let small = small_angle_error(0.01, -0.02, 0.005, ex, ey, ez);
        let exact = exact_error(0.01, -0.02, 0.005, ex, ey, ez);
        let diff = (small - exact).abs().max();
        // Second-order terms: products of two angles, about 1e-9 here.
        assert!(diff < 2e-9, "difference {diff}");
        assert!(diff > 0.0, "the two forms should differ at second order");
        // Its effect on a point 100 mm away is the first-order cross product.
        let p = transform_point(&small, &Vector3::new(100.0, 0.0, 0.0));
        let expected = Vector3::new(100.01, -0.02 + ez * 100.0, 0.005 - ey * 100.0);
        assert!(close(&p, &expected, 1e-12), "{p} vs {expected}");
    }

    #[test]
    fn rigid_inverse_undoes_the_transform() {
        let t = translation(3.0, -4.0, 5.0) * rot_z(0.3) * rot_x(-1.1) * rot_y(0.7);
        let i = rigid_inverse(&t);
        assert!((t * i - Htm::identity()).abs().max() < 1e-12);
        let general = t.try_inverse().expect("rigid transforms are invertible");
        assert!((general - i).abs().max() < 1e-12);
    }

    #[test]
    fn position_and_direction_read_back() {
        let t = translation(1.0, 2.0, 3.0) * rot_y(FRAC_PI_2);
        assert!(close(&position(&t), &Vector3::new(1.0, 2.0, 3.0), 1e-12));
        // The tool's Z axis turned +90° about Y points along +X.
        assert!(close(&z_direction(&t), &Vector3::x(), 1e-12));
    }
}
