//! Tests of `motion/rotation.rs`.

use super::*;

fn close(a: &[f64], b: &[f64], tol: f64) -> bool {
    a.iter().zip(b).all(|(x, y)| (x - y).abs() <= tol)
}

#[test]
fn hand_worked_quarter_turn_about_z_maps_x_to_y() {
    let q = axis_angle_to_quat([0.0, 0.0, std::f64::consts::FRAC_PI_2]);
    let v = quat_rotate(q, [1.0, 0.0, 0.0]);
    assert!(close(&v, &[0.0, 1.0, 0.0], 1e-12), "{v:?}");
    let m = quat_to_mat(q);
    assert!(close(
        &mat_vec(&m, [1.0, 0.0, 0.0]),
        &[0.0, 1.0, 0.0],
        1e-12
    ));
}

#[test]
fn euler_round_trips_in_every_order() {
    let angles = [0.3, -0.7, 1.1];
    for axes in EulerOrder::ALL_AXES {
        for intrinsic in [true, false] {
            let order = EulerOrder { axes, intrinsic };
            let q = euler_to_quat(angles, order);
            let back = quat_to_euler(q, order);
            assert!(close(&back, &angles, 1e-12), "{order}: {back:?}");
        }
    }
}

#[test]
fn intrinsic_zxy_is_rz_rx_ry() {
    let order: EulerOrder = "ZXY".parse().unwrap();
    let q = euler_to_quat([0.4, 0.5, 0.6], order);
    let expect = quat_mul(
        quat_mul(axis_quat(Axis::Z, 0.4), axis_quat(Axis::X, 0.5)),
        axis_quat(Axis::Y, 0.6),
    );
    assert!(geodesic_quat(q, expect) < 1e-12);
    let ext: EulerOrder = "yxz".parse().unwrap();
    let q2 = euler_to_quat([0.6, 0.5, 0.4], ext);
    assert!(geodesic_quat(q, q2) < 1e-12);
}

#[test]
fn gimbal_lock_still_reconstructs_the_rotation() {
    let order: EulerOrder = "XYZ".parse().unwrap();
    let q = euler_to_quat([0.3, std::f64::consts::FRAC_PI_2, 0.2], order);
    let e = quat_to_euler(q, order);
    assert!(geodesic_quat(q, euler_to_quat(e, order)) < 1e-7);
}

#[test]
fn sixd_and_matrix_round_trip() {
    let q = quat_normalize([0.3, -0.5, 0.2, 0.7]);
    let m = quat_to_mat(q);
    let back = sixd_to_mat(&mat_to_6d(&m));
    assert!(geodesic_quat(q, mat_to_quat(&back)) < 1e-12);
    assert!(geodesic_quat(q, mat_to_quat(&m)) < 1e-12);
}

#[test]
fn geodesic_of_known_angle() {
    let a = axis_angle_to_quat([0.0, 0.2, 0.0]);
    let b = axis_angle_to_quat([0.0, 0.9, 0.0]);
    assert!((geodesic_quat(a, b) - 0.7).abs() < 1e-12);
    // Angles past π wrap: a rotation of 2π - 0.1 is 0.1 from identity.
    let c = axis_angle_to_quat([2.0 * std::f64::consts::PI - 0.1, 0.0, 0.0]);
    assert!((geodesic_quat(IDENTITY_QUAT, c) - 0.1).abs() < 1e-12);
}

#[test]
fn slerp_halfway() {
    let a = IDENTITY_QUAT;
    let b = axis_angle_to_quat([0.0, 0.0, 1.0]);
    let h = slerp(a, b, 0.5);
    assert!(close(&quat_to_axis_angle(h), &[0.0, 0.0, 0.5], 1e-12));
}

#[test]
fn quat_between_aligns() {
    let from = normalize([1.0, 2.0, -0.5]).unwrap();
    let to = normalize([-0.3, 0.1, 0.9]).unwrap();
    let q = quat_between(from, to);
    assert!(close(&quat_rotate(q, from), &to, 1e-12));
    let q = quat_between(from, scale(from, -1.0));
    assert!(close(&quat_rotate(q, from), &scale(from, -1.0), 1e-12));
}
