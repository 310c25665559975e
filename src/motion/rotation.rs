//! Rotation representations and conversions.
//!
//! Conventions, stated once for the whole crate:
//! - Quaternions are `[w, x, y, z]` (scalar first), unit length, and act on
//!   column vectors: `v' = q v q*`.
//! - Matrices are row-major `[[f64; 3]; 3]` and act on column vectors
//!   (`v' = R v`), so `R = R_parent * R_local` composes parent-first.
//! - Axis-angle is a 3-vector whose direction is the axis and whose norm is the
//!   angle in radians (the SMPL / AIST++ convention).
//! - Euler angles are radians, in one of the 6 axis orders, either intrinsic
//!   (rotations about the moving axes — the BVH convention, where
//!   `CHANNELS Zrotation Xrotation Yrotation` means `R = Rz * Rx * Ry`) or
//!   extrinsic (about the fixed axes; `xyz` extrinsic equals `ZYX` intrinsic).
//! - 6D is the first two columns of the matrix (Zhou et al. 2019), read back by
//!   Gram–Schmidt.

use serde::{Deserialize, Serialize};
use std::fmt;
use std::str::FromStr;

pub type Vec3 = [f64; 3];
pub type Mat3 = [[f64; 3]; 3];
/// Unit quaternion, `[w, x, y, z]`.
pub type Quat = [f64; 4];

pub const IDENTITY_QUAT: Quat = [1.0, 0.0, 0.0, 0.0];
pub const IDENTITY_MAT: Mat3 = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];

// ---------------------------------------------------------------- vectors

#[inline]
pub fn add(a: Vec3, b: Vec3) -> Vec3 {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}
#[inline]
pub fn sub(a: Vec3, b: Vec3) -> Vec3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
#[inline]
pub fn scale(a: Vec3, s: f64) -> Vec3 {
    [a[0] * s, a[1] * s, a[2] * s]
}
#[inline]
pub fn dot(a: Vec3, b: Vec3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
#[inline]
pub fn cross(a: Vec3, b: Vec3) -> Vec3 {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}
#[inline]
pub fn norm(a: Vec3) -> f64 {
    dot(a, a).sqrt()
}
/// `a / |a|`, or `None` for a (near-)zero vector.
pub fn normalize(a: Vec3) -> Option<Vec3> {
    let n = norm(a);
    if n > 1e-12 && n.is_finite() {
        Some(scale(a, 1.0 / n))
    } else {
        None
    }
}
pub fn lerp3(a: Vec3, b: Vec3, t: f64) -> Vec3 {
    [
        a[0] + (b[0] - a[0]) * t,
        a[1] + (b[1] - a[1]) * t,
        a[2] + (b[2] - a[2]) * t,
    ]
}

// ---------------------------------------------------------------- matrices

pub fn mat_mul(a: &Mat3, b: &Mat3) -> Mat3 {
    let mut r = [[0.0; 3]; 3];
    for (i, row) in r.iter_mut().enumerate() {
        for (j, cell) in row.iter_mut().enumerate() {
            *cell = a[i][0] * b[0][j] + a[i][1] * b[1][j] + a[i][2] * b[2][j];
        }
    }
    r
}
pub fn mat_vec(a: &Mat3, v: Vec3) -> Vec3 {
    [dot(a[0], v), dot(a[1], v), dot(a[2], v)]
}
pub fn transpose(a: &Mat3) -> Mat3 {
    [
        [a[0][0], a[1][0], a[2][0]],
        [a[0][1], a[1][1], a[2][1]],
        [a[0][2], a[1][2], a[2][2]],
    ]
}

// ---------------------------------------------------------------- quaternions

pub fn quat_mul(a: Quat, b: Quat) -> Quat {
    [
        a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3],
        a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
        a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1],
        a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0],
    ]
}
pub fn quat_conj(q: Quat) -> Quat {
    [q[0], -q[1], -q[2], -q[3]]
}
pub fn quat_normalize(q: Quat) -> Quat {
    let n = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
    if n < 1e-300 || !n.is_finite() {
        return IDENTITY_QUAT;
    }
    [q[0] / n, q[1] / n, q[2] / n, q[3] / n]
}
pub fn quat_rotate(q: Quat, v: Vec3) -> Vec3 {
    let u = [q[1], q[2], q[3]];
    let t = scale(cross(u, v), 2.0);
    add(add(v, scale(t, q[0])), cross(u, t))
}

/// Spherical linear interpolation along the shorter arc; `t` in `[0, 1]`.
pub fn slerp(a: Quat, b: Quat, t: f64) -> Quat {
    let mut d = a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3];
    let mut b = b;
    if d < 0.0 {
        d = -d;
        b = [-b[0], -b[1], -b[2], -b[3]];
    }
    if d > 0.9995 {
        let r = [
            a[0] + (b[0] - a[0]) * t,
            a[1] + (b[1] - a[1]) * t,
            a[2] + (b[2] - a[2]) * t,
            a[3] + (b[3] - a[3]) * t,
        ];
        return quat_normalize(r);
    }
    let theta = d.clamp(-1.0, 1.0).acos();
    let s = theta.sin();
    let wa = ((1.0 - t) * theta).sin() / s;
    let wb = (t * theta).sin() / s;
    [
        wa * a[0] + wb * b[0],
        wa * a[1] + wb * b[1],
        wa * a[2] + wb * b[2],
        wa * a[3] + wb * b[3],
    ]
}

// ---------------------------------------------------------------- conversions

pub fn axis_angle_to_quat(aa: Vec3) -> Quat {
    let angle = norm(aa);
    if angle < 1e-12 {
        // First-order expansion keeps tiny rotations exact to rounding.
        return quat_normalize([1.0, aa[0] * 0.5, aa[1] * 0.5, aa[2] * 0.5]);
    }
    let h = angle * 0.5;
    let s = h.sin() / angle;
    [h.cos(), aa[0] * s, aa[1] * s, aa[2] * s]
}

/// Axis-angle with angle in `[0, π]`.
pub fn quat_to_axis_angle(q: Quat) -> Vec3 {
    let q = quat_normalize(q);
    let q = if q[0] < 0.0 {
        [-q[0], -q[1], -q[2], -q[3]]
    } else {
        q
    };
    let sv = (q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
    if sv < 1e-12 {
        return [2.0 * q[1], 2.0 * q[2], 2.0 * q[3]];
    }
    let angle = 2.0 * sv.atan2(q[0]);
    let k = angle / sv;
    [q[1] * k, q[2] * k, q[3] * k]
}

pub fn quat_to_mat(q: Quat) -> Mat3 {
    let [w, x, y, z] = quat_normalize(q);
    [
        [
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y - w * z),
            2.0 * (x * z + w * y),
        ],
        [
            2.0 * (x * y + w * z),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z - w * x),
        ],
        [
            2.0 * (x * z - w * y),
            2.0 * (y * z + w * x),
            1.0 - 2.0 * (x * x + y * y),
        ],
    ]
}

/// Shepperd's method; robust for every rotation.
pub fn mat_to_quat(m: &Mat3) -> Quat {
    let tr = m[0][0] + m[1][1] + m[2][2];
    let q = if tr > 0.0 {
        let s = (tr + 1.0).sqrt() * 2.0;
        [
            0.25 * s,
            (m[2][1] - m[1][2]) / s,
            (m[0][2] - m[2][0]) / s,
            (m[1][0] - m[0][1]) / s,
        ]
    } else if m[0][0] > m[1][1] && m[0][0] > m[2][2] {
        let s = (1.0 + m[0][0] - m[1][1] - m[2][2]).sqrt() * 2.0;
        [
            (m[2][1] - m[1][2]) / s,
            0.25 * s,
            (m[0][1] + m[1][0]) / s,
            (m[0][2] + m[2][0]) / s,
        ]
    } else if m[1][1] > m[2][2] {
        let s = (1.0 + m[1][1] - m[0][0] - m[2][2]).sqrt() * 2.0;
        [
            (m[0][2] - m[2][0]) / s,
            (m[0][1] + m[1][0]) / s,
            0.25 * s,
            (m[1][2] + m[2][1]) / s,
        ]
    } else {
        let s = (1.0 + m[2][2] - m[0][0] - m[1][1]).sqrt() * 2.0;
        [
            (m[1][0] - m[0][1]) / s,
            (m[0][2] + m[2][0]) / s,
            (m[1][2] + m[2][1]) / s,
            0.25 * s,
        ]
    };
    let q = quat_normalize(q);
    if q[0] < 0.0 {
        [-q[0], -q[1], -q[2], -q[3]]
    } else {
        q
    }
}

pub fn axis_angle_to_mat(aa: Vec3) -> Mat3 {
    quat_to_mat(axis_angle_to_quat(aa))
}
pub fn mat_to_axis_angle(m: &Mat3) -> Vec3 {
    quat_to_axis_angle(mat_to_quat(m))
}

/// The 6D representation: the first two columns of the matrix,
/// `[r00, r10, r20, r01, r11, r21]`.
pub fn mat_to_6d(m: &Mat3) -> [f64; 6] {
    [m[0][0], m[1][0], m[2][0], m[0][1], m[1][1], m[2][1]]
}

/// Gram–Schmidt on the two columns; the third is their cross product.
/// Degenerate input (zero or parallel columns) gives the identity.
pub fn sixd_to_mat(d: &[f64; 6]) -> Mat3 {
    let a1 = [d[0], d[1], d[2]];
    let a2 = [d[3], d[4], d[5]];
    let Some(b1) = normalize(a1) else {
        return IDENTITY_MAT;
    };
    let Some(b2) = normalize(sub(a2, scale(b1, dot(b1, a2)))) else {
        return IDENTITY_MAT;
    };
    let b3 = cross(b1, b2);
    [
        [b1[0], b2[0], b3[0]],
        [b1[1], b2[1], b3[1]],
        [b1[2], b2[2], b3[2]],
    ]
}

/// Geodesic angle (radians, in `[0, π]`) between two rotations: the angle of
/// `R_aᵀ R_b`.
pub fn geodesic_quat(a: Quat, b: Quat) -> f64 {
    // atan2 of the relative rotation's vector and scalar parts: accurate near
    // 0 where acos(dot) loses half the digits.
    let r = quat_mul(quat_conj(a), b);
    let v = (r[1] * r[1] + r[2] * r[2] + r[3] * r[3]).sqrt();
    2.0 * v.atan2(r[0].abs())
}
pub fn geodesic_axis_angle(a: Vec3, b: Vec3) -> f64 {
    geodesic_quat(axis_angle_to_quat(a), axis_angle_to_quat(b))
}

/// The shortest-arc rotation taking unit vector `from` onto unit vector `to`.
pub fn quat_between(from: Vec3, to: Vec3) -> Quat {
    let d = dot(from, to).clamp(-1.0, 1.0);
    if d < -1.0 + 1e-12 {
        // Opposite: rotate by π about any axis orthogonal to `from`.
        let mut axis = cross([1.0, 0.0, 0.0], from);
        if norm(axis) < 1e-6 {
            axis = cross([0.0, 1.0, 0.0], from);
        }
        let axis = normalize(axis).unwrap_or([0.0, 0.0, 1.0]);
        return [0.0, axis[0], axis[1], axis[2]];
    }
    let c = cross(from, to);
    quat_normalize([1.0 + d, c[0], c[1], c[2]])
}

// ---------------------------------------------------------------- Euler

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum Axis {
    X,
    Y,
    Z,
}

impl Axis {
    pub fn index(self) -> usize {
        match self {
            Axis::X => 0,
            Axis::Y => 1,
            Axis::Z => 2,
        }
    }
    pub fn unit(self) -> Vec3 {
        let mut v = [0.0; 3];
        v[self.index()] = 1.0;
        v
    }
    pub fn letter(self) -> char {
        match self {
            Axis::X => 'X',
            Axis::Y => 'Y',
            Axis::Z => 'Z',
        }
    }
}

/// An Euler convention: three distinct axes, applied intrinsically (moving
/// axes, `R = R_a0 R_a1 R_a2`) or extrinsically (fixed axes,
/// `R = R_a2 R_a1 R_a0`). Written like scipy: upper case = intrinsic
/// (`"ZXY"`), lower case = extrinsic (`"zxy"`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct EulerOrder {
    pub axes: [Axis; 3],
    pub intrinsic: bool,
}

impl EulerOrder {
    pub const ALL_AXES: [[Axis; 3]; 6] = [
        [Axis::X, Axis::Y, Axis::Z],
        [Axis::X, Axis::Z, Axis::Y],
        [Axis::Y, Axis::X, Axis::Z],
        [Axis::Y, Axis::Z, Axis::X],
        [Axis::Z, Axis::X, Axis::Y],
        [Axis::Z, Axis::Y, Axis::X],
    ];
    pub fn intrinsic(axes: [Axis; 3]) -> Self {
        EulerOrder {
            axes,
            intrinsic: true,
        }
    }
    /// The equivalent intrinsic order (an extrinsic `abc` is intrinsic `CBA`
    /// with the angles reversed): the order BVH lists its channels in.
    pub fn as_listed(self) -> [Axis; 3] {
        self.as_intrinsic_axes()
    }
    fn as_intrinsic_axes(self) -> [Axis; 3] {
        if self.intrinsic {
            self.axes
        } else {
            [self.axes[2], self.axes[1], self.axes[0]]
        }
    }
}

impl fmt::Display for EulerOrder {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for a in self.axes {
            let c = a.letter();
            write!(
                f,
                "{}",
                if self.intrinsic {
                    c
                } else {
                    c.to_ascii_lowercase()
                }
            )?;
        }
        Ok(())
    }
}

impl FromStr for EulerOrder {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let chars: Vec<char> = s.chars().collect();
        if chars.len() != 3 {
            return Err(format!("euler order '{s}' must have 3 letters"));
        }
        let upper = chars.iter().all(|c| c.is_ascii_uppercase());
        let lower = chars.iter().all(|c| c.is_ascii_lowercase());
        if !upper && !lower {
            return Err(format!(
                "euler order '{s}' mixes cases (upper = intrinsic, lower = extrinsic)"
            ));
        }
        let mut axes = [Axis::X; 3];
        for (i, c) in chars.iter().enumerate() {
            axes[i] = match c.to_ascii_uppercase() {
                'X' => Axis::X,
                'Y' => Axis::Y,
                'Z' => Axis::Z,
                _ => return Err(format!("euler order '{s}': '{c}' is not an axis")),
            };
        }
        if axes[0] == axes[1] || axes[1] == axes[2] || axes[0] == axes[2] {
            return Err(format!(
                "euler order '{s}': only Tait–Bryan orders (3 distinct axes) are supported"
            ));
        }
        Ok(EulerOrder {
            axes,
            intrinsic: upper,
        })
    }
}

pub fn axis_quat(axis: Axis, angle: f64) -> Quat {
    let h = angle * 0.5;
    let mut q = [h.cos(), 0.0, 0.0, 0.0];
    q[1 + axis.index()] = h.sin();
    q
}

/// Euler angles (radians, in the order's own axis order) to a quaternion.
pub fn euler_to_quat(angles: Vec3, order: EulerOrder) -> Quat {
    let (axes, ang) = if order.intrinsic {
        (order.axes, angles)
    } else {
        (order.as_intrinsic_axes(), [angles[2], angles[1], angles[0]])
    };
    let q = quat_mul(
        quat_mul(axis_quat(axes[0], ang[0]), axis_quat(axes[1], ang[1])),
        axis_quat(axes[2], ang[2]),
    );
    quat_normalize(q)
}

/// Quaternion to Euler angles (radians) in the given order. The middle angle
/// lies in `[-π/2, π/2]`; the outer two in `(-π, π]`. At gimbal lock the third
/// angle is set to 0 and the first absorbs the rotation (as scipy does).
pub fn quat_to_euler(q: Quat, order: EulerOrder) -> Vec3 {
    let m = quat_to_mat(q);
    let axes = order.as_intrinsic_axes();
    let (i, j, k) = (axes[0].index(), axes[1].index(), axes[2].index());
    // Parity: +1 when (i, j, k) is a cyclic permutation of (0, 1, 2).
    let sign = if (i + 1) % 3 == j { 1.0 } else { -1.0 };
    // For intrinsic R = R_i(a) R_j(b) R_k(c): m[i][k] = sign * sin(b).
    let sb = (sign * m[i][k]).clamp(-1.0, 1.0);
    let b = sb.asin();
    let (a, c);
    if sb.abs() < 1.0 - 1e-9 {
        a = (-sign * m[j][k]).atan2(m[k][k]);
        c = (-sign * m[i][j]).atan2(m[i][i]);
    } else {
        // Gimbal lock: c = 0, solve a from the remaining block.
        c = 0.0;
        a = (sign * m[k][j]).atan2(m[j][j]);
    }
    if order.intrinsic {
        [a, b, c]
    } else {
        [c, b, a]
    }
}

pub fn euler_to_mat(angles: Vec3, order: EulerOrder) -> Mat3 {
    quat_to_mat(euler_to_quat(angles, order))
}

/// Wrap an axis-angle vector so its norm lies in `[0, π]` (same rotation).
pub fn wrap_axis_angle(aa: Vec3) -> Vec3 {
    let angle = norm(aa);
    if angle <= std::f64::consts::PI || !angle.is_finite() {
        return aa;
    }
    quat_to_axis_angle(axis_angle_to_quat(aa))
}

/// Wrap every consecutive triple of a `[frames][channels]` row-major matrix
/// to an axis-angle with `|θ| ≤ π` (a trailing partial triple is left).
pub fn wrap_axis_angle_rows(data: &mut [f64], channels: usize) {
    for row in data.chunks_mut(channels) {
        for v in row.chunks_exact_mut(3) {
            let w = wrap_axis_angle([v[0], v[1], v[2]]);
            v.copy_from_slice(&w);
        }
    }
}

/// Make each joint's axis-angle continuous over time in a `[frames][channels]`
/// row-major matrix: every frame takes, among the equivalent vectors `v`,
/// `v·(1 − 2π/|v|)`, `v·(1 + 2π/|v|)`, the one nearest the previous frame's.
pub fn unwrap_axis_angle_rows(data: &mut [f64], channels: usize) {
    let tau = 2.0 * std::f64::consts::PI;
    let frames = data.len() / channels.max(1);
    for t in 1..frames {
        let (prev, cur) = data[(t - 1) * channels..(t + 1) * channels].split_at_mut(channels);
        for (p, v) in prev.chunks_exact(3).zip(cur.chunks_exact_mut(3)) {
            let th = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            if th < 1e-9 {
                continue;
            }
            let d = |w: &[f64; 3]| (0..3).map(|k| (w[k] - p[k]).powi(2)).sum::<f64>();
            let mut best = [v[0], v[1], v[2]];
            for s in [1.0 - tau / th, 1.0 + tau / th] {
                let w = [v[0] * s, v[1] * s, v[2] * s];
                if d(&w) < d(&best) {
                    best = w;
                }
            }
            v.copy_from_slice(&best);
        }
    }
}

#[cfg(test)]
mod tests;
