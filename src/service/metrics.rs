//! Prometheus metrics: request counts and latency histograms by transport,
//! route and outcome, served as text at `GET /metrics`. REST requests are
//! timed to the end of the handler; gRPC calls to their response headers
//! (for a stream, that is when streaming starts).

use std::collections::BTreeMap;
use std::sync::Mutex;
use std::task::{Context, Poll};
use std::time::Instant;

/// Upper bounds of the latency buckets, seconds.
pub const BUCKETS: [f64; 12] = [
    0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 10.0,
];

#[derive(Default, Clone)]
struct Entry {
    count: u64,
    sum: f64,
    buckets: [u64; 12],
}

/// The registry (one per server).
#[derive(Default)]
pub struct Metrics {
    by: Mutex<BTreeMap<(String, String, String), Entry>>,
}

impl Metrics {
    pub fn observe(&self, transport: &str, route: &str, code: &str, secs: f64) {
        let mut by = self.by.lock().unwrap_or_else(|p| p.into_inner());
        let e = by
            .entry((transport.into(), route.into(), code.into()))
            .or_default();
        e.count += 1;
        e.sum += secs;
        for (b, &le) in e.buckets.iter_mut().zip(&BUCKETS) {
            if secs <= le {
                *b += 1;
            }
        }
    }

    /// The Prometheus text exposition.
    pub fn render(&self) -> String {
        let by = self.by.lock().unwrap_or_else(|p| p.into_inner()).clone();
        let mut out = String::from(
            "# HELP choreo_requests_total Requests by transport, route and outcome (HTTP status or gRPC code).\n# TYPE choreo_requests_total counter\n",
        );
        for ((t, r, c), e) in &by {
            out += &format!(
                "choreo_requests_total{{transport=\"{t}\",route=\"{r}\",code=\"{c}\"}} {}\n",
                e.count
            );
        }
        out += "# HELP choreo_request_seconds Request latency.\n# TYPE choreo_request_seconds histogram\n";
        for ((t, r, c), e) in &by {
            let l = format!("transport=\"{t}\",route=\"{r}\",code=\"{c}\"");
            for (b, le) in e.buckets.iter().zip(BUCKETS) {
                out += &format!("choreo_request_seconds_bucket{{{l},le=\"{le}\"}} {b}\n");
            }
            out += &format!(
                "choreo_request_seconds_bucket{{{l},le=\"+Inf\"}} {}\n",
                e.count
            );
            out += &format!("choreo_request_seconds_sum{{{l}}} {}\n", e.sum);
            out += &format!("choreo_request_seconds_count{{{l}}} {}\n", e.count);
        }
        out
    }
}

/// A tower layer that records every gRPC call.
#[derive(Clone)]
pub struct GrpcMetricsLayer(pub std::sync::Arc<Metrics>);

impl<S> tower::Layer<S> for GrpcMetricsLayer {
    type Service = GrpcMetrics<S>;
    fn layer(&self, inner: S) -> Self::Service {
        GrpcMetrics {
            inner,
            m: self.0.clone(),
        }
    }
}

#[derive(Clone)]
pub struct GrpcMetrics<S> {
    inner: S,
    m: std::sync::Arc<Metrics>,
}

impl<S, B, R> tower::Service<http::Request<B>> for GrpcMetrics<S>
where
    S: tower::Service<http::Request<B>, Response = http::Response<R>> + Send + 'static,
    S::Future: Send + 'static,
{
    type Response = S::Response;
    type Error = S::Error;
    type Future = std::pin::Pin<
        Box<dyn std::future::Future<Output = Result<Self::Response, Self::Error>> + Send>,
    >;

    fn poll_ready(&mut self, cx: &mut Context<'_>) -> Poll<Result<(), Self::Error>> {
        self.inner.poll_ready(cx)
    }

    fn call(&mut self, mut req: http::Request<B>) -> Self::Future {
        let route = req.uri().path().to_string();
        let t0 = Instant::now();
        let id = request_id(req.headers());
        if let Ok(v) = http::HeaderValue::from_str(&id) {
            req.headers_mut().insert(REQUEST_ID, v);
        }
        let span = tracing::info_span!("request", id = %id, transport = "grpc", route = %route);
        let fut = {
            let _e = span.enter();
            self.inner.call(req)
        };
        let m = self.m.clone();
        Box::pin(tracing::Instrument::instrument(
            async move {
                let mut r = fut.await;
                let code = match &r {
                    // Errors before the body come as trailers-only headers.
                    Ok(resp) => resp
                        .headers()
                        .get("grpc-status")
                        .and_then(|v| v.to_str().ok())
                        .unwrap_or("0")
                        .to_string(),
                    Err(_) => "transport".to_string(),
                };
                let secs = t0.elapsed().as_secs_f64();
                m.observe("grpc", &route, &code, secs);
                tracing::info!(grpc_status = %code, duration_ms = secs * 1e3, "answered");
                if let (Ok(resp), Ok(v)) = (&mut r, http::HeaderValue::from_str(&id)) {
                    resp.headers_mut().insert(REQUEST_ID, v);
                }
                r
            },
            span,
        ))
    }
}

/// The header that carries a request's id both ways.
pub const REQUEST_ID: &str = "x-request-id";

/// The caller's request id when it sent a usable one (1–128 visible ASCII
/// characters), else a new one (16 hex digits, unique in this process).
pub fn request_id(headers: &http::HeaderMap) -> String {
    if let Some(v) = headers.get(REQUEST_ID).and_then(|v| v.to_str().ok()) {
        if !v.is_empty() && v.len() <= 128 && v.bytes().all(|b| b.is_ascii_graphic()) {
            return v.to_string();
        }
    }
    use std::sync::atomic::{AtomicU64, Ordering};
    static NEXT: AtomicU64 = AtomicU64::new(0);
    static BASE: std::sync::OnceLock<u64> = std::sync::OnceLock::new();
    let base = *BASE.get_or_init(|| {
        let t = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos() as u64);
        t ^ (std::process::id() as u64).rotate_left(32)
    });
    let n = NEXT.fetch_add(1, Ordering::Relaxed);
    // A bijective mix, so consecutive ids do not look consecutive.
    let mut x = base.wrapping_add(n.wrapping_mul(0x9E37_79B9_7F4A_7C15));
    x ^= x >> 31;
    x = x.wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x ^= x >> 29;
    format!("{x:016x}")
}
