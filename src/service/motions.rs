//! The archive: ingest (with a video link and a collection), get, export,
//! delete and list stored motions, collections, and the audit trail. Every
//! operation sees only the caller's collections.

use super::input::prefix;
use super::{auth, internal, ApiError, Choreo, MotionInput};
use crate::motion::io::bvh::{write_bvh, BvhWriteOptions};
use crate::motion::io::json::write_json;
use crate::motion::io::ReadOptions;
use crate::motion::{Labels, Motion};
pub use crate::search::ingest::Stored;
use crate::search::ingest::{load_motion, load_source, parse_source, IngestOptions};
use crate::search::IngestOutcome;
use crate::store::{MotionRow, VideoLink};

/// A video link as a request gives it: a path or URL of at most 2,048
/// characters, and a finite offset.
fn check_video(v: &VideoLink) -> Result<(), ApiError> {
    if v.video.is_empty() || v.video.len() > 2048 || v.video.chars().any(char::is_control) {
        return Err(ApiError::invalid(
            "video",
            "must be a path or URL of 1 to 2,048 characters without control characters",
        ));
    }
    if !v.video_offset_s.is_finite() {
        return Err(ApiError::invalid(
            "video_offset_s",
            "must be a finite number of seconds",
        ));
    }
    Ok(())
}
/// Who made a write, for the audit trail.
#[derive(Clone, Debug)]
pub struct Actor {
    /// The token's name (`anonymous` never writes).
    pub name: String,
    /// The request's id (`x-request-id`), as in the server's log line.
    pub request_id: String,
}

/// Store a motion (an upload in any supported format, or an inline motion,
/// kept as choreo JSON) with `labels` added; the next query sees it.
/// Idempotent by content hash: labels sent with content already stored are
/// merged into its labels, and the answer gives them.
pub async fn ingest(
    state: &Choreo,
    input: MotionInput,
    labels: Labels,
    video: Option<VideoLink>,
    collection: Option<String>,
    who: &auth::Principal,
    actor: &Actor,
) -> Result<IngestOutcome, ApiError> {
    // The collection must exist and be the writer's: an unknown one and one
    // not granted get the same answer, so that nothing leaks.
    let collection = collection.unwrap_or_else(|| crate::search::ingest::DEFAULT_COLLECTION.into());
    if !who.sees(&collection)
        || !state
            .store
            .collections()
            .await
            .map_err(ApiError::from)?
            .contains(&collection)
    {
        return Err(ApiError::Missing {
            field: "collection".into(),
            reason: format!("no collection {collection:?}"),
        });
    }
    if let Some(v) = &video {
        check_video(v)?;
    }
    let (name, bytes, read) = match input {
        MotionInput::Inline(m) => {
            let stem: String = m
                .name
                .chars()
                .map(|c| {
                    if c.is_ascii_alphanumeric() || c == '_' || c == '-' {
                        c
                    } else {
                        '_'
                    }
                })
                .collect();
            (
                format!("{}.json", if stem.is_empty() { "motion" } else { &stem }),
                write_json(&m),
                ReadOptions::default(),
            )
        }
        MotionInput::File { name, bytes, read } => {
            if name.is_empty() {
                return Err(ApiError::invalid(
                    "motion.file.name",
                    "an upload needs its file name (the extension gives the format)",
                ));
            }
            (name, bytes, read)
        }
        MotionInput::Stored(_) => {
            return Err(ApiError::invalid(
                "motion",
                "a stored motion cannot be ingested again",
            ))
        }
    };
    let opts = IngestOptions {
        extra_labels: labels,
        keep_files: true,
        read,
        video,
        collection,
        ..Default::default()
    };
    let _permit = state
        .workers
        .clone()
        .try_acquire_owned()
        .map_err(|_| ApiError::Busy("every worker is busy; retry ingest later".into()))?;
    let out = state
        .searcher
        .ingest(&name, bytes, &opts)
        .await
        .map_err(ApiError::from)?
        .map_err(|e| prefix("motion", e.into()))?;
    let (action, target) = match out.stored {
        Stored::New { motion_id, windows } => (
            "ingest",
            format!("motion {motion_id} from {name} ({windows} windows)"),
        ),
        Stored::Existing { motion_id } => (
            "ingest-existing",
            format!(
                "motion {motion_id} from {name}{}",
                if out.merged_labels.is_some() {
                    ", labels merged"
                } else {
                    ", nothing written"
                }
            ),
        ),
    };
    state
        .store
        .audit_append(&actor.name, action, &target, &actor.request_id)
        .await
        .map_err(ApiError::from)?;
    Ok(out)
}

/// The newest `limit` (1..=10,000) audit entries, newest first.
pub async fn audit(state: &Choreo, limit: i64) -> Result<Vec<crate::store::AuditRow>, ApiError> {
    if !(1..=10_000).contains(&limit) {
        return Err(ApiError::invalid(
            "limit",
            format!("{limit} is not in 1..=10000"),
        ));
    }
    state.store.audit(limit).await.map_err(ApiError::from)
}

/// A stored motion's row, when the caller may see it: a motion of a
/// collection it cannot see is not found, the same answer as no motion.
pub async fn visible(
    state: &Choreo,
    id: i64,
    who: &auth::Principal,
) -> Result<MotionRow, ApiError> {
    state
        .store
        .motion(id)
        .await
        .map_err(ApiError::from)?
        .filter(|r| who.sees(&r.collection))
        .ok_or_else(|| ApiError::NotFound(format!("motion {id}")))
}

/// A stored motion and its row.
pub async fn get_motion(
    state: &Choreo,
    id: i64,
    who: &auth::Principal,
) -> Result<(MotionRow, Motion), ApiError> {
    visible(state, id, who).await?;
    load_motion(&state.store, id)
        .await?
        .ok_or_else(|| ApiError::NotFound(format!("motion {id}")))
}

/// A stored motion as BVH text: a BVH source is given back byte for byte
/// (unparsed), any other is written (SMPL skeleton, ZXY Euler, centimetres).
pub async fn export_bvh(
    state: &Choreo,
    id: i64,
    who: &auth::Principal,
) -> Result<String, ApiError> {
    visible(state, id, who).await?;
    let (row, name, bytes) = load_source(&state.store, id)
        .await?
        .ok_or_else(|| ApiError::NotFound(format!("motion {id}")))?;
    if row.format == "bvh" {
        return String::from_utf8(bytes).map_err(internal);
    }
    let m = parse_source(id, name, bytes, row.read_options.clone()).await?;
    state
        .heavy("export", move || {
            Ok(write_bvh(&m, &BvhWriteOptions::default())?)
        })
        .await
}

/// A stored motion as binary glTF (skinned skeleton and its animation).
pub async fn export_glb(
    state: &Choreo,
    id: i64,
    who: &auth::Principal,
) -> Result<Vec<u8>, ApiError> {
    let (_, m) = get_motion(state, id, who).await?;
    state
        .heavy("export", move || {
            Ok(crate::motion::io::gltf::write_glb(&m)?)
        })
        .await
}

/// Remove a stored motion and everything derived from it.
pub async fn delete_motion(
    state: &Choreo,
    id: i64,
    who: &auth::Principal,
    actor: &Actor,
) -> Result<(), ApiError> {
    visible(state, id, who).await?;
    if !state.searcher.delete(id).await.map_err(ApiError::from)? {
        return Err(ApiError::NotFound(format!("motion {id}")));
    }
    state
        .store
        .audit_append(
            &actor.name,
            "delete",
            &format!("motion {id}"),
            &actor.request_id,
        )
        .await
        .map_err(ApiError::from)
}

pub async fn list_motions(
    state: &Choreo,
    who: &auth::Principal,
) -> Result<Vec<MotionRow>, ApiError> {
    let mut rows = state.store.motions().await.map_err(ApiError::from)?;
    rows.retain(|r| who.sees(&r.collection));
    Ok(rows)
}

/// The collections the caller may see.
pub async fn list_collections(
    state: &Choreo,
    who: &auth::Principal,
) -> Result<Vec<String>, ApiError> {
    let mut all = state.store.collections().await.map_err(ApiError::from)?;
    all.retain(|c| who.sees(c));
    Ok(all)
}

/// Create a collection (`admin`); `true` when new. Recorded in the audit
/// trail.
pub async fn create_collection(
    state: &Choreo,
    name: &str,
    actor: &Actor,
) -> Result<bool, ApiError> {
    if !auth::valid_collection_name(name) {
        return Err(ApiError::invalid(
            "name",
            "a collection's name is 1 to 64 letters, digits and - _ . only",
        ));
    }
    let created = state
        .store
        .create_collection(name)
        .await
        .map_err(ApiError::from)?;
    if created {
        state
            .store
            .audit_append(
                &actor.name,
                "collection-create",
                &format!("collection {name}"),
                &actor.request_id,
            )
            .await
            .map_err(ApiError::from)?;
    }
    Ok(created)
}
