//! What a query request is checked against before it searches: its
//! numbers and segment, its label filters (a filter nothing can match is
//! an error, naming what there is), and the stored embeddings a query by
//! stored id can reuse.

use super::{QueryError, QueryRequest, Searcher};
use crate::features::{window_starts, Embedding, FEATURE_FPS, WINDOW};
use crate::motion::MotionError;
use std::collections::{HashMap, HashSet};

impl Searcher {
    /// Check a request's numbers and find its segment's first frame (60 fps).
    pub(super) fn segment(
        &self,
        req: &QueryRequest,
        name: &str,
        len: usize,
    ) -> Result<usize, QueryError> {
        if req.k == 0 || req.k > 1000 {
            return Err(
                MotionError::invalid(name, "k", format!("{} is not in 1..=1000", req.k)).into(),
            );
        }
        if req.frames < WINDOW {
            return Err(MotionError::invalid(
                name,
                "frames",
                format!(
                    "{} frames is shorter than a {WINDOW}-frame window",
                    req.frames
                ),
            )
            .into());
        }
        if !(req.start_s.is_finite() && req.start_s >= 0.0) {
            return Err(MotionError::invalid(
                name,
                "start",
                format!("{} s is not a start time", req.start_s),
            )
            .into());
        }
        let start = (req.start_s * FEATURE_FPS).round() as usize;
        if start + req.frames > len {
            return Err(MotionError::invalid(
                name,
                "frames",
                format!(
                    "segment {start}..{} (60 fps frames) runs past the clip's {len} frames ({:.2} s)",
                    start + req.frames,
                    len as f64 / FEATURE_FPS
                ),
            )
            .into());
        }
        Ok(start)
    }

    /// A filter that can match nothing is a mistake, not an empty answer:
    /// refused as `filters.KIND`, naming the kinds or values stored.
    /// Filters that no stored motion (of `visible`, when given) can match
    /// are refused, with the kinds and values there are.
    pub(super) async fn check_filters(
        &self,
        filters: &[(String, String)],
        visible: Option<&HashSet<i64>>,
    ) -> Result<(), QueryError> {
        let known = match visible {
            None => self.store.label_values().await?,
            // Only what the caller may see is named.
            Some(v) => {
                let mut out =
                    std::collections::BTreeMap::<String, std::collections::BTreeSet<String>>::new();
                for m in self
                    .catalog()
                    .motions
                    .values()
                    .filter(|m| v.contains(&m.id))
                {
                    for (k, val) in &m.labels {
                        out.entry(k.clone()).or_default().insert(val.clone());
                    }
                }
                out
            }
        };
        let list = |it: &mut dyn Iterator<Item = &String>| {
            let all: Vec<&String> = it.collect();
            let shown: Vec<&str> = all.iter().take(20).map(|s| s.as_str()).collect();
            match all.len().saturating_sub(20) {
                0 => shown.join(", "),
                more => format!("{} and {more} more", shown.join(", ")),
            }
        };
        for (k, v) in filters {
            let reason = match known.get(k) {
                None => format!(
                    "no stored motion has a '{k}' label (kinds: {})",
                    list(&mut known.keys())
                ),
                Some(values) if !values.contains(v) => format!(
                    "no stored motion has {k}={v} (values: {})",
                    list(&mut values.iter())
                ),
                Some(_) => continue,
            };
            return Err(MotionError::invalid("query", &format!("filters.{k}"), reason).into());
        }
        Ok(())
    }

    /// Stored embeddings for the query's windows that fall on the stored
    /// grid of a stored motion (STFT and DCT; PCA is cheap to recompute).
    pub(super) async fn reusable(
        &self,
        req: &QueryRequest,
        id: i64,
        start: usize,
    ) -> Result<HashMap<usize, Vec<f32>>, QueryError> {
        let mut out = HashMap::new();
        if req.embedding == Embedding::Pca {
            return Ok(out);
        }
        let on_grid: Vec<(usize, i64)> = {
            let c = self.catalog();
            let by_start: HashMap<i64, i64> = c
                .by_motion
                .get(&id)
                .into_iter()
                .flatten()
                .filter_map(|w| c.windows.get(w).map(|r| (r.start_frame, *w)))
                .collect();
            window_starts(req.frames, 32)
                .into_iter()
                .filter_map(|s| by_start.get(&((start + s) as i64)).map(|w| (s, *w)))
                .collect()
        };
        for (s, wid) in on_grid {
            if let Some(v) = self.store.embedding(wid, req.embedding).await? {
                out.insert(s, v);
            }
        }
        Ok(out)
    }
}
