//! choreo: search, transform, generate and classify human motion capture.
//!
//! Module map:
//! - [`motion`] — pure motion core: skeletons, rotations, clips, ops,
//!   forward kinematics, readers/writers (AIST++ pickle, AMASS npz, BVH),
//!   retargeting onto the SMPL 13-joint subset.
//! - [`data`] — where the real corpora live (`CHOREO_DATA`).

pub mod data;
pub mod motion;
