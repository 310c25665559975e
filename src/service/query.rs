//! Query: the stored windows most like a clip ([`crate::search`] does the
//! search; this file checks the request, applies its defaults and access).

use super::input::MotionInput;
use super::motions::visible;
use super::{auth, ApiError, Choreo};
use crate::features::Embedding;
use crate::index::Metric;
use crate::search::{QueryHit, QueryRequest, QuerySource};

/// Window length (frames at 60 fps) when a request names none.
pub const DEFAULT_FRAMES: usize = 128;
/// Hits returned when a request names no `k`.
pub const DEFAULT_K: usize = 10;
/// The most hits one request may ask for.
pub const MAX_K: usize = 1000;

/// The embedding a request names, or the default: `pose` for motion from
/// video (keypoints, or SMPL from an estimator), `stft` otherwise. REST,
/// gRPC and the CLI all choose it here.
pub fn embedding_or_default(name: &str, footage: bool) -> Result<Embedding, ApiError> {
    match name {
        "" if footage => Ok(Embedding::Pose),
        "" => Ok(Embedding::Stft),
        e => Embedding::parse(e).ok_or_else(|| {
            ApiError::invalid(
                "embedding",
                format!("'{e}' is not stft, dct, pca, pose or lm"),
            )
        }),
    }
}

/// The metric a request names, or the default (cosine).
pub fn metric_or_default(name: &str) -> Result<Metric, ApiError> {
    match name {
        "" => Ok(Metric::Cosine),
        m => Metric::parse(m).ok_or_else(|| {
            ApiError::invalid("metric", format!("'{m}' is not cosine or euclidean"))
        }),
    }
}

/// A query request as every transport gives it; an empty string or a zero
/// means "the default" (the constants and functions above).
pub struct QueryParams {
    pub motion: MotionInput,
    pub start_s: f64,
    pub frames: usize,
    pub k: usize,
    pub embedding: String,
    pub metric: String,
    pub filters: Vec<(String, String)>,
    pub exact: bool,
}

pub async fn query(
    state: &Choreo,
    p: QueryParams,
    who: &auth::Principal,
) -> Result<Vec<QueryHit>, ApiError> {
    // Motion from video (keypoints, SMPL from an estimator) is searched by
    // the pose embedding unless the request names another. A stored id is
    // looked up once: it must be the caller's to see.
    let (footage, source) = match p.motion {
        MotionInput::File { read, name, bytes } => {
            let footage = read.keypoints.is_some() || read.fps.is_some();
            let m = state
                .resolve("motion", MotionInput::File { read, name, bytes }, who)
                .await?;
            (footage, QuerySource::Motion(m))
        }
        MotionInput::Stored(id) => {
            // The catalog's copy of the row (collection and format never
            // change) spares a database read; a motion it has not seen, or
            // that the caller may not see, is looked up in the store.
            let format = match state.searcher.motion_access(id) {
                Some((collection, format)) if who.sees(&collection) => format,
                _ => {
                    visible(state, id, who)
                        .await
                        .map_err(|e| match e {
                            ApiError::NotFound(_) => ApiError::Missing {
                                field: "motion.id".into(),
                                reason: format!("no stored motion {id}"),
                            },
                            other => other,
                        })?
                        .format
                }
            };
            (
                format == "keypoints" || format == "smpl",
                QuerySource::Stored(id),
            )
        }
        inline => (
            false,
            QuerySource::Motion(state.resolve("motion", inline, who).await?),
        ),
    };
    let embedding = embedding_or_default(&p.embedding, footage)?;
    let metric = metric_or_default(&p.metric)?;
    if p.k > MAX_K {
        return Err(ApiError::invalid("k", format!("{}; at most {MAX_K}", p.k)));
    }
    let req = QueryRequest {
        source,
        start_s: p.start_s,
        frames: if p.frames == 0 {
            DEFAULT_FRAMES
        } else {
            p.frames
        },
        k: if p.k == 0 { DEFAULT_K } else { p.k },
        embedding,
        metric,
        filters: p.filters,
        exact: p.exact,
        collections: who.collections.clone(),
    };
    let _permit = state
        .light
        .clone()
        .acquire_owned()
        .await
        .map_err(|_| ApiError::Busy("the query pool is closed".into()))?;
    let mut hits = state.searcher.query(req).await?;
    for h in &mut hits {
        h.source_path = public_source(&h.source_path);
    }
    Ok(hits)
}

/// A motion's source as API clients see it: its file name, never the
/// server's path to it (`../shared/data/aistpp/motions/x.pkl` → `x.pkl`).
/// The command line, run where the files are, keeps the whole path.
pub fn public_source(path: &str) -> String {
    std::path::Path::new(path)
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| path.to_string())
}
