//! The one error vocabulary every endpoint answers with, its two
//! translations (HTTP status, gRPC code, and the JSON body's `code`), and
//! how the layers' errors (motion, query, store, load) map onto it.

use crate::motion::MotionError;
use crate::search::ingest::LoadError;
use crate::search::QueryError;
use crate::store::StoreError;

/// Errors every endpoint can answer with.
#[derive(Debug, thiserror::Error)]
pub enum ApiError {
    /// The request is wrong: names the field and why.
    #[error("{field}: {reason}")]
    Invalid { field: String, reason: String },
    #[error("not found: {0}")]
    NotFound(String),
    /// A request field names something that does not exist (a stored id).
    #[error("{field}: {reason}")]
    Missing { field: String, reason: String },
    /// Every worker permit is taken: try again later.
    #[error("busy: {0}")]
    Busy(String),
    /// The request is larger than the server takes (`--max-body-mb`).
    #[error("too large: {0}")]
    TooLarge(String),
    /// The capability is not loaded (no model).
    #[error("unavailable: {0}")]
    Unavailable(String),
    /// A write without the right bearer token.
    #[error("unauthenticated: {0}")]
    Unauthenticated(String),
    /// The token lacks the scope, or the server has no way to grant it.
    #[error("permission denied: {0}")]
    PermissionDenied(String),
    /// The caller is over its request rate: retry after the given seconds.
    #[error("rate limited: {reason}")]
    RateLimited { reason: String, retry_after_s: u64 },
    #[error("internal error: {0}")]
    Internal(String),
}

impl ApiError {
    pub fn invalid(field: impl Into<String>, reason: impl Into<String>) -> ApiError {
        ApiError::Invalid {
            field: field.into(),
            reason: reason.into(),
        }
    }
    /// The HTTP translation.
    pub fn http_status(&self) -> u16 {
        match self {
            ApiError::Invalid { .. } => 400,
            ApiError::NotFound(_) | ApiError::Missing { .. } => 404,
            ApiError::Busy(_) | ApiError::RateLimited { .. } => 429,
            ApiError::TooLarge(_) => 413,
            ApiError::Unavailable(_) => 503,
            ApiError::Unauthenticated(_) => 401,
            ApiError::PermissionDenied(_) => 403,
            ApiError::Internal(_) => 500,
        }
    }
    /// The gRPC translation.
    pub fn grpc_code(&self) -> tonic::Code {
        match self {
            ApiError::Invalid { .. } => tonic::Code::InvalidArgument,
            ApiError::NotFound(_) | ApiError::Missing { .. } => tonic::Code::NotFound,
            ApiError::Busy(_) | ApiError::TooLarge(_) | ApiError::RateLimited { .. } => {
                tonic::Code::ResourceExhausted
            }
            ApiError::Unavailable(_) => tonic::Code::Unavailable,
            ApiError::Unauthenticated(_) => tonic::Code::Unauthenticated,
            ApiError::PermissionDenied(_) => tonic::Code::PermissionDenied,
            ApiError::Internal(_) => tonic::Code::Internal,
        }
    }
    /// The error body both REST and the WebSockets send:
    /// `{"error": {"code", "field"?, "reason"}}`.
    pub fn body(&self) -> serde_json::Value {
        match self {
            ApiError::Invalid { field, reason } | ApiError::Missing { field, reason } => {
                serde_json::json!({"error": {"code": self.kind(), "field": field, "reason": reason}})
            }
            other => {
                serde_json::json!({"error": {"code": other.kind(), "reason": other.to_string()}})
            }
        }
    }
    pub fn kind(&self) -> &'static str {
        match self {
            ApiError::Invalid { .. } => "invalid_argument",
            ApiError::NotFound(_) | ApiError::Missing { .. } => "not_found",
            ApiError::Busy(_) | ApiError::TooLarge(_) | ApiError::RateLimited { .. } => {
                "resource_exhausted"
            }
            ApiError::Unavailable(_) => "unavailable",
            ApiError::Unauthenticated(_) => "unauthenticated",
            ApiError::PermissionDenied(_) => "permission_denied",
            ApiError::Internal(_) => "internal",
        }
    }
}

impl From<MotionError> for ApiError {
    fn from(e: MotionError) -> Self {
        match e {
            MotionError::Invalid {
                file,
                field,
                reason,
            } => ApiError::Invalid {
                field,
                reason: format!("{file}: {reason}"),
            },
            MotionError::Unsupported { file, reason } => ApiError::Invalid {
                field: "motion".into(),
                reason: format!("{file}: {reason}"),
            },
            e @ MotionError::Io { .. } => ApiError::Internal(e.to_string()),
        }
    }
}

impl From<QueryError> for ApiError {
    fn from(e: QueryError) -> Self {
        match e {
            QueryError::Motion(m) => m.into(),
            QueryError::NotFound(id) => ApiError::Missing {
                field: "motion.id".into(),
                reason: format!("no stored motion {id}"),
            },
            QueryError::Store(e) => e.into(),
            other => ApiError::Internal(other.to_string()),
        }
    }
}

impl From<LoadError> for ApiError {
    fn from(e: LoadError) -> Self {
        match e {
            LoadError::Motion(m) => m.into(),
            // The row is there but its source file moved or changed (it was
            // ingested from disk without --keep-files).
            LoadError::Gone(reason) => ApiError::NotFound(reason),
            LoadError::Store(e) => e.into(),
        }
    }
}

/// A store error as the API answers it: an unreachable database (a
/// PostgreSQL restart) is 503 / UNAVAILABLE, so clients retry; anything
/// else is an internal error.
impl From<StoreError> for ApiError {
    fn from(e: StoreError) -> Self {
        match e {
            StoreError::Unavailable { .. } => {
                ApiError::Unavailable("the store is unavailable; retry shortly".into())
            }
            other => ApiError::Internal(other.to_string()),
        }
    }
}
