//! choreo: search, transform, generate and classify human motion capture.
//!
//! Module map:
//! - [`motion`] — pure motion core: skeletons, rotations, clips, ops,
//!   forward kinematics, readers/writers (AIST++ pickle, AMASS npz, BVH),
//!   retargeting onto the SMPL 13-joint subset.
//! - [`data`] — where the real corpora live (`CHOREO_DATA`).
//! - [`features`] — pure: STFT / DCT / PCA window embeddings.
//! - [`index`] — `AnnIndex`: exact (the oracle) and HNSW, cosine or Euclidean.
//! - [`tokenize`] — pure: motion ↔ tokens (uniform, quantile, JPEG-like tile
//!   codec) and the language model vocabulary.
//! - [`keyframes`] — pure: keyframe selection and in-betweens.
//! - [`store`] — the archive's SQL store (SQLite, PostgreSQL).
//! - [`search`] — the live searcher over the store: indexes, writes,
//!   maintenance, the ingest pipeline.
//! - [`lm`] — the model runtime (tract, onnxruntime), sampling, duet.
//! - [`service`] — the application core: [`service::Choreo`] and one file
//!   per use case.
//! - [`api`] — the transports (REST, WebSocket, gRPC): wire types only.
//! - [`eval`] — the thesis-table evaluations.
//!
//! Reading a motion and asking where its joints are:
//!
//! ```
//! use choreo::motion::{Labels, Motion, Skeleton};
//! // One frame of the SMPL body at rest, pelvis 0.9 m above the origin.
//! let sk = Skeleton::smpl24();
//! let trans = vec![[0.0, 0.9 - sk.offsets[0][1], 0.0]];
//! let m = Motion::new("rest", 60.0, sk, trans, vec![[0.0; 3]; 24], Labels::new()).unwrap();
//! let p = m.positions(); // [frames][joints] metres
//! assert!((p[0][1] - 0.9).abs() < 1e-12);
//! // The head is above the pelvis, the ankles below it.
//! assert!(p[15][1] > p[0][1] && p[7][1] < p[0][1]);
//! ```

pub mod api;
pub mod audio;
pub mod data;
pub mod eval;
pub mod features;
pub mod index;
pub mod keyframes;
pub mod lm;
pub mod motion;
pub mod plot;
pub mod search;
pub mod server;
pub mod service;
pub mod store;
pub mod tokenize;
#[cfg(feature = "train")]
pub mod train;
