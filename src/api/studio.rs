//! The web studio at `/`: a page and its script and style, built from
//! `web/src` by `web/build.mjs` (esbuild over three.js from npm) into
//! `web/dist`, committed, and embedded here, so `cargo build` needs no Node
//! and a user installs nothing. The assets hold no archive content: they are
//! served without a token; everything they show comes through the API with
//! the user's token.

use axum::http::header;
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::Router;

const INDEX: &str = include_str!("../../web/dist/index.html");
const SCRIPT: &str = include_str!("../../web/dist/studio.js");
const STYLE: &str = include_str!("../../web/dist/studio.css");

fn asset(content_type: &'static str, body: &'static str, cache: &'static str) -> Response {
    (
        [
            (header::CONTENT_TYPE, content_type),
            (header::CACHE_CONTROL, cache),
            (header::X_CONTENT_TYPE_OPTIONS, "nosniff"),
        ],
        body,
    )
        .into_response()
}

/// `/`, `/studio/studio.js`, `/studio/studio.css`. The page is never cached
/// (it names the build of its script); the script and style are cached for
/// an hour.
pub fn routes<S: Clone + Send + Sync + 'static>() -> Router<S> {
    Router::new()
        .route(
            "/",
            get(|| async { asset("text/html; charset=utf-8", INDEX, "no-cache") }),
        )
        .route(
            "/studio/studio.js",
            get(|| async {
                asset(
                    "text/javascript; charset=utf-8",
                    SCRIPT,
                    "public, max-age=3600",
                )
            }),
        )
        .route(
            "/studio/studio.css",
            get(|| async { asset("text/css; charset=utf-8", STYLE, "public, max-age=3600") }),
        )
}
