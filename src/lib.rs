//! choreo: search, transform, generate and classify human motion capture.
//!
//! Module map:
//! - [`motion`] — pure motion core: skeletons, rotations, clips, ops,
//!   forward kinematics, readers/writers (AIST++ pickle, AMASS npz, BVH),
//!   retargeting onto the SMPL 13-joint subset.
//! - [`data`] — where the real corpora live (`CHOREO_DATA`).
//! - [`features`] — pure: STFT / DCT / PCA window embeddings.
//! - [`index`] — `AnnIndex`: exact (the oracle) and HNSW, cosine or Euclidean.

pub mod data;
pub mod features;
pub mod index;
pub mod motion;
pub mod service;
pub mod store;
