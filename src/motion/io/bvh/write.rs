//! The BVH writer: any motion on its own skeleton, optionally in the
//! channel layout a BVH read gave (so a BVH source comes back byte for
//! byte), in the unit asked for.

use super::*;
use std::fmt::Write as _;

#[derive(Clone, Debug)]
pub struct BvhWriteOptions<'a> {
    /// Metres per unit written (0.01 = centimetres, what most tools expect).
    pub metres_per_unit: f64,
    /// Channel layout to reproduce where joint names match (from a BVH read).
    pub layout: Option<&'a BvhLayout>,
    /// Rotation order for joints the layout does not cover (intrinsic).
    pub order: EulerOrder,
    /// Decimal places of every number.
    pub decimals: usize,
}

impl Default for BvhWriteOptions<'_> {
    fn default() -> Self {
        BvhWriteOptions {
            metres_per_unit: 0.01,
            layout: None,
            order: EulerOrder::intrinsic([Axis::Z, Axis::X, Axis::Y]),
            decimals: 6,
        }
    }
}

fn fmt_num(out: &mut String, v: f64, decimals: usize) {
    let v = if v == 0.0 { 0.0 } else { v }; // no "-0.000000"
    let _ = write!(out, "{v:.decimals$}");
}

/// Write a motion as BVH text.
pub fn write_bvh(m: &Motion, opts: &BvhWriteOptions<'_>) -> Result<String, MotionError> {
    m.validate()?;
    let u = opts.metres_per_unit;
    if !(u.is_finite() && u > 0.0) {
        return Err(MotionError::invalid(
            &m.name,
            "metres_per_unit",
            format!("{u} is not a positive scale"),
        ));
    }
    let sk = &m.skeleton;
    let nj = sk.len();
    let default_rot: Vec<Channel> = opts
        .order
        .as_listed()
        .iter()
        .map(|a| Channel::Rot(*a))
        .collect();
    // Channels per joint.
    let mut channels: Vec<Vec<Channel>> = Vec::with_capacity(nj);
    for j in 0..nj {
        let from_layout = opts
            .layout
            .and_then(|l| l.channels_of(&sk.names[j]))
            .filter(|c| {
                let rots: Vec<_> = c.iter().filter(|x| matches!(x, Channel::Rot(_))).collect();
                rots.len() == 3
                    && (j != 0 || c.iter().filter(|x| matches!(x, Channel::Pos(_))).count() == 3)
            });
        channels.push(match from_layout {
            Some(c) => c.to_vec(),
            None if j == 0 => {
                let mut c = vec![
                    Channel::Pos(Axis::X),
                    Channel::Pos(Axis::Y),
                    Channel::Pos(Axis::Z),
                ];
                c.extend(&default_rot);
                c
            }
            None => default_rot.clone(),
        });
    }
    let mut out = String::with_capacity(64 * nj + m.frames() * nj * 30);
    out.push_str("HIERARCHY\n");
    write_joint(&mut out, m, 0, 0, &channels, opts);
    out.push_str("MOTION\n");
    let _ = writeln!(out, "Frames: {}", m.frames());
    let _ = writeln!(out, "Frame Time: {:.9}", 1.0 / m.fps);
    // Frame rows follow the hierarchy's depth-first order.
    let mut order = Vec::with_capacity(nj);
    let mut todo = vec![0usize];
    while let Some(j) = todo.pop() {
        order.push(j);
        let mut ch = sk.children(j);
        ch.reverse();
        todo.extend(ch);
    }
    let mut prev: Vec<Vec<f64>> = vec![Vec::new(); nj];
    for f in 0..m.frames() {
        let mut first = true;
        for &j in &order {
            let q = axis_angle_to_quat(m.rot(f, j));
            let rot_axes: Vec<Axis> = channels[j]
                .iter()
                .filter_map(|c| {
                    if let Channel::Rot(a) = c {
                        Some(*a)
                    } else {
                        None
                    }
                })
                .collect();
            let order = EulerOrder::intrinsic([rot_axes[0], rot_axes[1], rot_axes[2]]);
            let mut e: Vec<f64> = quat_to_euler(q, order)
                .iter()
                .map(|v| v.to_degrees())
                .collect();
            // Keep each channel continuous with the previous frame.
            if let Some(p) = prev.get(j).filter(|p| !p.is_empty()) {
                for (v, pv) in e.iter_mut().zip(p) {
                    *v += 360.0 * ((pv - *v) / 360.0).round();
                }
            }
            let local = if j == 0 {
                scale(add(sk.offsets[0], m.trans[f]), 1.0 / u)
            } else {
                scale(sk.offsets[j], 1.0 / u)
            };
            let mut ri = 0;
            for c in &channels[j] {
                if !first {
                    out.push(' ');
                }
                first = false;
                match c {
                    Channel::Pos(a) => fmt_num(&mut out, local[a.index()], opts.decimals),
                    Channel::Rot(_) => {
                        fmt_num(&mut out, e[ri], opts.decimals);
                        ri += 1;
                    }
                }
            }
            prev[j] = std::mem::take(&mut e);
        }
        out.push('\n');
    }
    Ok(out)
}

fn write_joint(
    out: &mut String,
    m: &Motion,
    j: usize,
    depth: usize,
    channels: &[Vec<Channel>],
    opts: &BvhWriteOptions<'_>,
) {
    let sk = &m.skeleton;
    let ind = "  ".repeat(depth);
    let u = opts.metres_per_unit;
    let kw = if depth == 0 { "ROOT" } else { "JOINT" };
    let _ = writeln!(out, "{ind}{kw} {}", sk.names[j]);
    let _ = writeln!(out, "{ind}{{");
    let off = scale(sk.offsets[j], 1.0 / u);
    let _ = write!(out, "{ind}  OFFSET ");
    for (k, v) in off.iter().enumerate() {
        if k > 0 {
            out.push(' ');
        }
        fmt_num(out, *v, opts.decimals);
    }
    out.push('\n');
    let names: Vec<String> = channels[j].iter().map(|c| c.name()).collect();
    let _ = writeln!(out, "{ind}  CHANNELS {} {}", names.len(), names.join(" "));
    let children = sk.children(j);
    for &c in &children {
        write_joint(out, m, c, depth + 1, channels, opts);
    }
    let mut ends: Vec<Vec3> = sk
        .end_sites
        .iter()
        .filter(|e| e.parent == j)
        .map(|e| e.offset)
        .collect();
    if children.is_empty() && ends.is_empty() {
        // Every leaf needs an End Site; continue the joint's own bone a little.
        ends.push(scale(sk.offsets[j], 0.25));
    }
    for e in ends {
        let e = scale(e, 1.0 / u);
        let _ = writeln!(out, "{ind}  End Site");
        let _ = writeln!(out, "{ind}  {{");
        let _ = write!(out, "{ind}    OFFSET ");
        for (k, v) in e.iter().enumerate() {
            if k > 0 {
                out.push(' ');
            }
            fmt_num(out, *v, opts.decimals);
        }
        out.push('\n');
        let _ = writeln!(out, "{ind}  }}");
    }
    let _ = writeln!(out, "{ind}}}");
}
