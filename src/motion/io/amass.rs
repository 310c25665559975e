//! AMASS `.npz` (a zip of `.npy` arrays): `poses` `(N, 156)` SMPL-H (or 72 SMPL,
//! 165 SMPL-X) axis-angle whose first 66 values are the 22 body joints,
//! `trans` `(N, 3)` metres, `mocap_framerate` (or `mocap_frame_rate`).
//!
//! AMASS's world is z up; choreo's is y up. Reading turns the world by −90°
//! about x (`(x, y, z) → (x, z, −y)`), applied to the root orientation and to
//! the pelvis's world position; writing turns it back.

use super::npy::{parse_npy, NdArray};
use crate::motion::clip::{Motion, MAX_FRAMES};
use crate::motion::labels;
use crate::motion::rotation::*;
use crate::motion::skeleton::Skeleton;
use crate::motion::MotionError;
use std::io::{Cursor, Read, Write};

/// Largest decompressed array accepted from an archive (a 10 M-frame 165-wide
/// f64 array would be 13 GB; AMASS's longest takes are a few MB).
const MAX_ENTRY_BYTES: u64 = 1 << 30;

/// The rotation taking AMASS's z-up world to choreo's y-up world.
fn z_up_to_y_up() -> Quat {
    axis_angle_to_quat([-std::f64::consts::FRAC_PI_2, 0.0, 0.0])
}

pub(crate) fn entry(
    file: &str,
    zip: &mut zip::ZipArchive<Cursor<&[u8]>>,
    names: &[&str],
) -> Result<Option<NdArray>, MotionError> {
    for name in names {
        let fname = format!("{name}.npy");
        let mut f = match zip.by_name(&fname) {
            Ok(f) => f,
            Err(zip::result::ZipError::FileNotFound) => continue,
            Err(e) => {
                return Err(MotionError::invalid(
                    file,
                    *name,
                    format!("cannot open archive entry: {e}"),
                ))
            }
        };
        let mut buf = Vec::new();
        (&mut f)
            .take(MAX_ENTRY_BYTES + 1)
            .read_to_end(&mut buf)
            .map_err(|e| MotionError::invalid(file, *name, format!("cannot decompress: {e}")))?;
        if buf.len() as u64 > MAX_ENTRY_BYTES {
            return Err(MotionError::invalid(file, *name, "array larger than 1 GiB"));
        }
        return parse_npy(&buf)
            .map(Some)
            .map_err(|r| MotionError::invalid(file, *name, r));
    }
    Ok(None)
}

pub fn read_amass_npz(file: &str, bytes: &[u8]) -> Result<Motion, MotionError> {
    let mut zip = zip::ZipArchive::new(Cursor::new(bytes)).map_err(|e| {
        MotionError::invalid(file, "npz", format!("not a readable zip archive: {e}"))
    })?;
    let poses = entry(file, &mut zip, &["poses"])?
        .ok_or_else(|| MotionError::invalid(file, "poses", "missing from the archive"))?;
    let trans = entry(file, &mut zip, &["trans"])?
        .ok_or_else(|| MotionError::invalid(file, "trans", "missing from the archive"))?;
    let fps = entry(file, &mut zip, &["mocap_framerate", "mocap_frame_rate"])?
        .ok_or_else(|| MotionError::invalid(file, "mocap_framerate", "missing from the archive"))?
        .scalar()
        .ok_or_else(|| MotionError::invalid(file, "mocap_framerate", "is not a single number"))?;
    let (n, w) = poses
        .dims2()
        .filter(|_| poses.shape.len() == 2)
        .ok_or_else(|| {
            MotionError::invalid(file, "poses", format!("shape {:?} is not 2-D", poses.shape))
        })?;
    if w < 66 {
        return Err(MotionError::invalid(
            file,
            "poses",
            format!("has {w} columns, needs at least 66 (22 body joints)"),
        ));
    }
    if n == 0 || n > MAX_FRAMES {
        return Err(MotionError::invalid(
            file,
            "poses",
            format!("{n} frames is not in 1..={MAX_FRAMES}"),
        ));
    }
    if trans.dims2() != Some((n, 3)) || trans.shape.len() != 2 {
        return Err(MotionError::invalid(
            file,
            "trans",
            format!("shape {:?} does not match {n} frames x 3", trans.shape),
        ));
    }
    let sk = Skeleton::smpl24();
    let o0 = sk.offsets[0];
    let turn = z_up_to_y_up();
    // A 72-wide SMPL array carries all 24 joints; wider ones carry 22 body
    // joints then hands, and the SMPL palms stay at rest.
    let body = if w == 72 { 24 } else { 22 };
    let mut rotations = vec![[0.0; 3]; n * 24];
    let mut out_trans = Vec::with_capacity(n);
    for f in 0..n {
        let row = &poses.data[f * w..(f + 1) * w];
        for j in 0..body {
            rotations[f * 24 + j] = [row[3 * j], row[3 * j + 1], row[3 * j + 2]];
        }
        rotations[f * 24] =
            quat_to_axis_angle(quat_mul(turn, axis_angle_to_quat(rotations[f * 24])));
        let t = [
            trans.data[3 * f],
            trans.data[3 * f + 1],
            trans.data[3 * f + 2],
        ];
        // Pelvis world position p = o0 + t turns with the world.
        out_trans.push(sub(quat_rotate(turn, add(o0, t)), o0));
    }
    let mut l = labels::from_name(file);
    l.entry("corpus".into()).or_insert_with(|| "amass".into());
    Motion::new(file, fps, sk, out_trans, rotations, l)
}

/// Write an SMPL motion as an AMASS-style `.npz` (`poses` (N,156) with the
/// hands at rest, `trans`, `mocap_framerate`, z up). An SMPL-13 motion
/// (generated, or reduced with `convert --joints smpl13`) keeps its 13
/// joints in their SMPL slots and the other joints at rest.
pub fn write_amass_npz(m: &Motion) -> Result<Vec<u8>, MotionError> {
    if m.skeleton.kind == "smpl13" {
        return write_amass_npz(&m.smpl13_to_smpl24()?);
    }
    if m.skeleton.kind != "smpl24" {
        return Err(MotionError::invalid(
            &m.name,
            "skeleton",
            "AMASS output needs an SMPL-24 or SMPL-13 motion (convert --joints smpl24 retargets others)",
        ));
    }
    let n = m.frames();
    let back = quat_conj(z_up_to_y_up());
    let o0 = m.skeleton.offsets[0];
    let mut poses = vec![0.0; n * 156];
    let mut trans = Vec::with_capacity(n * 3);
    for f in 0..n {
        for j in 0..22 {
            let mut r = m.rot(f, j);
            if j == 0 {
                r = quat_to_axis_angle(quat_mul(back, axis_angle_to_quat(r)));
            }
            poses[f * 156 + 3 * j..f * 156 + 3 * j + 3].copy_from_slice(&r);
        }
        let t = sub(quat_rotate(back, add(o0, m.trans[f])), o0);
        trans.extend_from_slice(&t);
    }
    let arrays = [
        (
            "poses.npy",
            NdArray {
                shape: vec![n, 156],
                data: poses,
            },
        ),
        (
            "trans.npy",
            NdArray {
                shape: vec![n, 3],
                data: trans,
            },
        ),
        (
            "mocap_framerate.npy",
            NdArray {
                shape: vec![],
                data: vec![m.fps],
            },
        ),
    ];
    write_npz(&m.name, &arrays)
}

/// A zip of `.npy` arrays (deflated).
pub(crate) fn write_npz(name: &str, arrays: &[(&str, NdArray)]) -> Result<Vec<u8>, MotionError> {
    let mut out = Cursor::new(Vec::new());
    {
        let mut zw = zip::ZipWriter::new(&mut out);
        let opts = zip::write::SimpleFileOptions::default()
            .compression_method(zip::CompressionMethod::Deflated);
        for (entry, a) in arrays {
            zw.start_file(*entry, opts)
                .and_then(|_| zw.write_all(&a.to_npy(false)).map_err(Into::into))
                .map_err(|e| MotionError::invalid(name, "npz", e.to_string()))?;
        }
        zw.finish()
            .map_err(|e| MotionError::invalid(name, "npz", e.to_string()))?;
    }
    Ok(out.into_inner())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::motion::skeleton::SMPL13_FROM_24;

    /// An SMPL-13 motion writes as AMASS npz: its joints in their SMPL
    /// slots, the others at rest, the root path kept.
    #[test]
    fn smpl13_writes_as_amass_npz() {
        let rots: Vec<[f64; 3]> = (0..30 * 24)
            .map(|i| {
                let (f, j) = ((i / 24) as f64, (i % 24) as f64);
                [0.01 * j, 0.2 * (0.3 * f + j).sin(), -0.1]
            })
            .collect();
        let trans = (0..30).map(|f| [0.02 * f as f64, 0.9, 0.1]).collect();
        let m24 = Motion::new(
            "x",
            30.0,
            crate::motion::Skeleton::smpl24(),
            trans,
            rots,
            Default::default(),
        )
        .unwrap();
        let m13 = m24.to_smpl13().unwrap();
        let back = read_amass_npz("x.npz", &write_amass_npz(&m13).unwrap()).unwrap();
        assert_eq!((back.skeleton.kind.as_str(), back.frames()), ("smpl24", 30));
        for f in 0..30 {
            for (i, &k) in SMPL13_FROM_24.iter().enumerate() {
                let (a, b) = (m13.rot(f, i), back.rot(f, k));
                assert!(
                    (0..3).all(|c| (a[c] - b[c]).abs() < 1e-9),
                    "{f} {k}: {a:?} {b:?}"
                );
            }
            for (a, b) in m13.trans[f].iter().zip(&back.trans[f]) {
                assert!((a - b).abs() < 1e-9);
            }
        }
        let kept: std::collections::HashSet<usize> = SMPL13_FROM_24.iter().copied().collect();
        for k in (0..24).filter(|k| !kept.contains(k)) {
            assert!(back.rot(10, k).iter().all(|x| x.abs() < 1e-12), "{k}");
        }
    }
}
