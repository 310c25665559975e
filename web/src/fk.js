// Forward kinematics for choreo's motion JSON: local axis-angle rotations
// (radians) on a skeleton of parents and rest offsets (metres, each in its
// parent's frame; the root's offset is its rest position), plus the root
// translation. The same arithmetic as the server's `Motion::positions`; the
// browser test checks the two agree.

/** Axis-angle [x, y, z] to a unit quaternion [w, x, y, z]. */
export function axisAngleToQuat(v) {
  const a = Math.hypot(v[0], v[1], v[2]);
  if (a < 1e-12) return [1, 0, 0, 0];
  const s = Math.sin(a / 2) / a;
  return [Math.cos(a / 2), v[0] * s, v[1] * s, v[2] * s];
}

export function quatMul(p, q) {
  return [
    p[0] * q[0] - p[1] * q[1] - p[2] * q[2] - p[3] * q[3],
    p[0] * q[1] + p[1] * q[0] + p[2] * q[3] - p[3] * q[2],
    p[0] * q[2] - p[1] * q[3] + p[2] * q[0] + p[3] * q[1],
    p[0] * q[3] + p[1] * q[2] - p[2] * q[1] + p[3] * q[0],
  ];
}

export function quatRotate(q, v) {
  // v' = v + 2w (u × v) + 2 u × (u × v), u = (x, y, z)
  const [w, x, y, z] = q;
  const cx = y * v[2] - z * v[1];
  const cy = z * v[0] - x * v[2];
  const cz = x * v[1] - y * v[0];
  const ccx = y * cz - z * cy;
  const ccy = z * cx - x * cz;
  const ccz = x * cy - y * cx;
  return [v[0] + 2 * (w * cx + ccx), v[1] + 2 * (w * cy + ccy), v[2] + 2 * (w * cz + ccz)];
}

/** Joint positions of one frame: a Float32Array of joints × 3. */
export function framePositions(skeleton, rotations, translation, out) {
  const j = skeleton.parents.length;
  const pos = out || new Float32Array(j * 3);
  const glob = new Array(j);
  for (let k = 0; k < j; k++) {
    const local = axisAngleToQuat(rotations[k] || [0, 0, 0]);
    const p = skeleton.parents[k];
    const o = skeleton.offsets[k];
    if (p === null || p === undefined) {
      glob[k] = local;
      pos[k * 3] = o[0] + translation[0];
      pos[k * 3 + 1] = o[1] + translation[1];
      pos[k * 3 + 2] = o[2] + translation[2];
    } else {
      glob[k] = quatMul(glob[p], local);
      const r = quatRotate(glob[p], o);
      pos[k * 3] = pos[p * 3] + r[0];
      pos[k * 3 + 1] = pos[p * 3 + 1] + r[1];
      pos[k * 3 + 2] = pos[p * 3 + 2] + r[2];
    }
  }
  return pos;
}

/** Every frame of a motion JSON (`{fps, rotations, translation}`). */
export function motionPositions(skeleton, motion) {
  const n = motion.rotations.length;
  const frames = new Array(n);
  for (let f = 0; f < n; f++) {
    frames[f] = framePositions(skeleton, motion.rotations[f], motion.translation[f] || [0, 0, 0]);
  }
  return frames;
}
