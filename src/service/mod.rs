//! The application core. [`Choreo`] owns the store, the live searcher, the
//! models, access rules, metrics and the two CPU pools; each use case is one
//! file and takes `&Choreo`, a transport-neutral request and the caller
//! ([`auth::Principal`]). REST (`api::http`), gRPC (`api::grpc`), the
//! WebSocket and the CLI only convert their wire types to these requests and
//! back (ARCHITECTURE rule 1), so the same request gives the same result,
//! names and errors on every transport.
//!
//! - [`input`]: where a request's motion comes from, and resolving it;
//! - [`query`], [`interpolate`], [`lowpass`], [`keyframes`], [`generate`]
//!   (one-shot, stream), [`duet`], [`classify`], [`motions`] (ingest, get,
//!   export, delete, collections, audit);
//! - [`error`]: the one error vocabulary with its HTTP and gRPC tables;
//! - [`auth`]: tokens, scopes, collections and per-caller limits;
//! - [`metrics`]: request counts and latencies.

pub mod auth;
pub mod classify;
pub mod duet;
mod error;
pub mod generate;
pub mod input;
pub mod interpolate;
pub mod keyframes;
pub mod lowpass;
pub mod metrics;
pub mod motions;
pub mod query;

use crate::search::Searcher;
use crate::store::Store;
pub use error::ApiError;
pub use input::MotionInput;
use std::sync::Arc;
use tokio::sync::Semaphore;

/// The application core: the store, the live searcher, the models, the
/// access rules and the two CPU pools. REST, gRPC and the WebSocket hold one
/// `Arc<Choreo>` and call the use cases with it.
pub struct Choreo {
    pub store: Store,
    /// The live searcher: writes go through it and reach its indexes at
    /// once; its maintenance runs in the background.
    pub searcher: Arc<Searcher>,
    /// Tokens, scopes, open reads and per-client limits.
    pub auth: Arc<auth::Auth>,
    /// Permits for CPU-heavy requests (interpolate, lowpass, keyframes,
    /// generate, classify; a stream holds one for its whole life).
    pub workers: Arc<Semaphore>,
    /// Permits for queries (the light pool: one per core). Queries wait for
    /// one rather than fail, and never take a heavy permit, so they keep
    /// flowing while generation holds every worker.
    pub light: Arc<Semaphore>,
    /// The motion language model, when one is installed.
    pub model: Option<crate::lm::model::MotionModel>,
    /// The model's style exemplars (`exemplars.json` beside it), when it has
    /// them: a generation with labels and no seed starts from one.
    pub exemplars: Option<Arc<crate::lm::exemplars::Exemplars>>,
    /// The learned in-betweener, when one is installed.
    pub inbetweener: Option<Arc<crate::lm::inbetween::Inbetweener>>,
    /// Request counts and latencies for `/metrics`.
    pub metrics: Arc<metrics::Metrics>,
}

impl Choreo {
    pub fn new(
        store: Store,
        searcher: Searcher,
        workers: usize,
        model: Option<crate::lm::model::MotionModel>,
        inbetweener: Option<Arc<crate::lm::inbetween::Inbetweener>>,
        auth: Arc<auth::Auth>,
    ) -> Choreo {
        Choreo {
            store,
            searcher: Arc::new(searcher),
            auth,
            workers: Arc::new(Semaphore::new(workers.max(1))),
            light: Arc::new(Semaphore::new(
                std::thread::available_parallelism().map_or(2, |n| n.get()),
            )),
            model,
            exemplars: None,
            inbetweener,
            metrics: Default::default(),
        }
    }

    /// The same core with the model's style exemplars.
    pub fn with_exemplars(
        mut self,
        exemplars: Option<Arc<crate::lm::exemplars::Exemplars>>,
    ) -> Choreo {
        self.exemplars = exemplars;
        self
    }

    /// The live searcher.
    pub fn searcher(&self) -> Arc<Searcher> {
        self.searcher.clone()
    }

    /// May the caller go ahead with a request that needs `need`? `header`
    /// is the `Authorization` header (or gRPC metadata) as sent, `addr` the
    /// peer (the anonymous caller's rate-limit key). Takes one request from
    /// the caller's bucket. Returns who the caller is.
    pub fn authorize(
        &self,
        header: Option<&str>,
        need: auth::Scope,
        addr: Option<std::net::IpAddr>,
    ) -> Result<auth::Principal, ApiError> {
        // The scheme is case-insensitive (RFC 9110 §11.1).
        let token = match header {
            None => None,
            Some(h) => Some(
                h.split_once(' ')
                    .filter(|(scheme, _)| scheme.eq_ignore_ascii_case("bearer"))
                    .map(|(_, t)| t.trim())
                    .ok_or_else(|| {
                        ApiError::Unauthenticated(
                            "the Authorization header must be `Bearer <token>`".into(),
                        )
                    })?,
            ),
        };
        let who = self.auth.authorize(token, need)?;
        self.auth.admit(&who, addr)?;
        Ok(who)
    }

    /// Run CPU work on the blocking pool under a worker permit; no permit
    /// free → [`ApiError::Busy`] at once.
    pub async fn heavy<T: Send + 'static>(
        &self,
        what: &str,
        f: impl FnOnce() -> Result<T, ApiError> + Send + 'static,
    ) -> Result<T, ApiError> {
        let permit = self
            .workers
            .clone()
            .try_acquire_owned()
            .map_err(|_| ApiError::Busy(format!("every worker is busy; retry {what} later")))?;
        tokio::task::spawn_blocking(move || {
            let _p = permit;
            f()
        })
        .await
        .map_err(|e| ApiError::Internal(format!("{what} worker failed: {e}")))?
    }
}

pub(crate) fn internal(e: impl std::fmt::Display) -> ApiError {
    ApiError::Internal(e.to_string())
}
