//! `choreo serve`: one tokio process, REST (axum) and gRPC (tonic) on two
//! ports over one shared state, graceful shutdown on SIGINT / SIGTERM.

use crate::api::{grpc, http};
use crate::index::hnsw::HnswParams;
use crate::search::Searcher;
use crate::service::Choreo;
use crate::store::Store;
use anyhow::{Context, Result};
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;
use tokio::sync::watch;

/// Every setting is a flag and an environment variable.
#[derive(clap::Args, Clone, Debug)]
pub struct ServeConfig {
    /// Folder holding the SQLite store (choreo.db) and its HNSW indexes.
    #[arg(long, env = "CHOREO_DATA_DIR", default_value = "choreo-data")]
    pub data_dir: PathBuf,
    /// The store: a PostgreSQL URL (`postgres://USER:PASSWORD@HOST:PORT/DB`)
    /// that several replicas share, or a SQLite file. Default: the embedded
    /// SQLite file DATA_DIR/choreo.db. With PostgreSQL, --data-dir keeps
    /// only this replica's index dumps.
    #[arg(long, env = "CHOREO_STORE", hide_env_values = true)]
    pub store: Option<String>,
    /// How often (ms) the server looks for writes made by other processes
    /// on the same store (other replicas, `choreo ingest`); a write through
    /// any replica is visible through this one within about this long.
    #[arg(long, env = "CHOREO_SYNC_MS", default_value_t = 500)]
    pub sync_ms: u64,
    /// Address both listeners bind to.
    #[arg(long, env = "CHOREO_BIND", default_value = "127.0.0.1")]
    pub bind: String,
    /// REST port (0 = any free port).
    #[arg(long, env = "CHOREO_HTTP_PORT", default_value_t = 8080)]
    pub http_port: u16,
    /// gRPC port (0 = any free port).
    #[arg(long, env = "CHOREO_GRPC_PORT", default_value_t = 50051)]
    pub grpc_port: u16,
    /// Largest request body / gRPC message, MiB.
    #[arg(long, env = "CHOREO_MAX_BODY_MB", default_value_t = 64)]
    pub max_body_mb: usize,
    /// Requests that may run CPU-heavy work at once; more get 429 /
    /// RESOURCE_EXHAUSTED.
    #[arg(long, env = "CHOREO_WORKERS", default_value_t = 2)]
    pub workers: usize,
    /// Folders or files to ingest at start-up (skipped when already stored).
    #[arg(long, env = "CHOREO_INGEST", value_delimiter = ',')]
    pub ingest: Vec<PathBuf>,
    /// The motion model: a folder with manifest.json and its ONNX graphs
    /// (written by choreo-train; the manifest's `kind` says which model,
    /// `motion-lm` or `motion-frame-lm`). Missing folder = generate and
    /// classify answer 503; a broken model stops start-up.
    #[arg(long, env = "CHOREO_MODEL", default_value = "models/default")]
    pub model: PathBuf,
    /// Which runtime runs the models: tract (built in), ort (onnxruntime;
    /// needs a build with the `onnxruntime` feature and the library from
    /// the onnxruntime pip wheel, at --ort-lib or ORT_DYLIB_PATH), or auto
    /// (ort where that library loads, else tract; the log says which).
    #[arg(long, env = "CHOREO_RUNTIME", default_value = "tract")]
    pub runtime: crate::lm::engine::Runtime,
    /// The onnxruntime shared library for --runtime ort (default:
    /// ORT_DYLIB_PATH).
    #[arg(long)]
    pub ort_lib: Option<PathBuf>,
    /// What runs the frame model's local step (once a slot, 42 times a
    /// frame): `kernel`, choreo's own (checked against the graph at load;
    /// where it differs the runtime keeps it, and the log says why), or
    /// `graph`, the runtime's run of the exported graph.
    #[arg(long, env = "CHOREO_LOCAL_STEP", default_value = "kernel")]
    pub local_step: crate::lm::engine::LocalStep,
    /// The learned in-betweener for `keyframes` with `inbetween: learned`
    /// (a folder written by `choreo-train inbetween`); missing = 503.
    #[arg(long, env = "CHOREO_INBETWEENER", default_value = "models/inbetween")]
    pub inbetweener: PathBuf,
    /// One bearer token with every scope (read, write, admin), named
    /// `token` in the audit trail. Without any token, writes answer 403.
    #[arg(long, env = "CHOREO_TOKEN", hide_env_values = true)]
    pub token: Option<String>,
    /// A token file: one `name scopes sha256:<hex>` line per token (scopes
    /// read, write, admin; `choreo token new NAME` makes a line). Read again
    /// when it changes, so removing a line revokes a token.
    #[arg(long, env = "CHOREO_TOKENS")]
    pub tokens: Option<PathBuf>,
    /// Reads (query, list, get, export, the model endpoints) need no token.
    /// Without it, and without any token, the server refuses to start.
    #[arg(long, env = "CHOREO_PUBLIC_READ")]
    pub public_read: bool,
    /// Requests per second per client (a token, or an address for
    /// anonymous reads); past it, 429 with Retry-After. 0 = no limit.
    #[arg(long, env = "CHOREO_RATE_LIMIT", default_value_t = 0.0)]
    pub rate_limit: f64,
    /// The bucket of --rate-limit: requests a client may make at once.
    #[arg(long, env = "CHOREO_RATE_BURST", default_value_t = 20.0)]
    pub rate_burst: f64,
    /// An origin (`https://studio.example.org`) whose pages may call the
    /// REST API from a browser (CORS, preflight answered); repeat or
    /// comma-separate for several, `*` for any (development). None: no
    /// cross-origin calls. Writes still need the token.
    #[arg(
        long = "cors-origin",
        env = "CHOREO_CORS_ORIGIN",
        value_delimiter = ','
    )]
    pub cors_origins: Vec<String>,
    /// Log lines as text or as one JSON object each (to stderr; the level
    /// from `RUST_LOG`, default `info`). Every request logs one line with
    /// its id (echoed in `x-request-id`), route, status and duration.
    #[arg(long, env = "CHOREO_LOG_FORMAT", value_enum, default_value = "text")]
    pub log_format: LogFormat,
    /// The HNSW graph: `flat` (choreo's flat arrays, faster queries) or
    /// `hnsw_rs`. An index saved by the other one is rebuilt.
    #[arg(long, env = "CHOREO_HNSW_BACKEND", value_enum, default_value = "flat")]
    pub hnsw_backend: crate::index::hnsw::Backend,
    /// How the HNSW indexes store vectors: `f32`, or `f16` (half the
    /// memory and memory traffic, the same recall: each index's ef_search
    /// is still calibrated against exact f32 search; scores are then
    /// rounded to about 1e-3; flat graph only). An index saved with the
    /// other type is rebuilt.
    #[arg(long, env = "CHOREO_VECTOR_DTYPE", value_enum, default_value = "f32")]
    pub vector_dtype: crate::index::VectorDtype,
    /// HNSW links per node (`M`; level 0 keeps 2M). An index saved with
    /// another M is rebuilt.
    #[arg(long, env = "CHOREO_HNSW_M", default_value_t = crate::index::hnsw::HnswParams::default().m)]
    pub hnsw_m: usize,
    /// HNSW candidate list while building (`efConstruction`). An index
    /// saved with another value is rebuilt.
    #[arg(long, env = "CHOREO_HNSW_EF_CONSTRUCTION", default_value_t = crate::index::hnsw::HnswParams::default().ef_construction)]
    pub hnsw_ef_construction: usize,
    /// Megabytes of stored motions' channels kept in memory for queries by
    /// stored id (least recently used leave first; 0: every query reads
    /// its segment from the store).
    #[arg(long, env = "CHOREO_CHANNEL_CACHE_MB", default_value_t = crate::search::DEFAULT_CHANNEL_CACHE_MB)]
    pub channel_cache_mb: usize,
}

#[derive(clap::ValueEnum, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum LogFormat {
    #[default]
    Text,
    Json,
}

/// Install the process's log subscriber (once; later calls do nothing).
pub fn init_logging(format: LogFormat) {
    use tracing_subscriber::EnvFilter;
    let filter = EnvFilter::try_from_default_env().unwrap_or_else(|_| EnvFilter::new("info"));
    let b = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()));
    let _ = match format {
        LogFormat::Text => b.try_init(),
        LogFormat::Json => b.json().with_current_span(true).try_init(),
    };
}

/// The CORS layer for `--cors-origin`, or an error naming the bad origin.
pub fn cors_layer(origins: &[String]) -> Result<Option<tower_http::cors::CorsLayer>> {
    use axum::http::{header, HeaderValue, Method};
    use tower_http::cors::{AllowOrigin, CorsLayer};
    if origins.is_empty() {
        return Ok(None);
    }
    let allow = if origins.iter().any(|o| o == "*") {
        AllowOrigin::any()
    } else {
        let mut list = Vec::new();
        for o in origins {
            let ok = (o.starts_with("http://") || o.starts_with("https://"))
                && !o.trim_end_matches('/').contains(['?', '#'])
                && o.split("://")
                    .nth(1)
                    .is_some_and(|h| !h.is_empty() && !h.contains('/'));
            if !ok {
                anyhow::bail!(
                    "--cors-origin {o:?}: an origin is scheme://host[:port] (no path), or *"
                );
            }
            list.push(HeaderValue::from_str(o).with_context(|| format!("--cors-origin {o:?}"))?);
        }
        AllowOrigin::list(list)
    };
    Ok(Some(
        CorsLayer::new()
            .allow_origin(allow)
            .allow_methods([Method::GET, Method::POST, Method::DELETE, Method::OPTIONS])
            .allow_headers([header::CONTENT_TYPE, header::AUTHORIZATION])
            .expose_headers([header::RETRY_AFTER, header::ALLOW])
            .max_age(std::time::Duration::from_secs(600)),
    ))
}

/// A running server.
pub struct Running {
    pub http: SocketAddr,
    pub grpc: SocketAddr,
    stop: watch::Sender<bool>,
    tasks: Vec<tokio::task::JoinHandle<Result<()>>>,
}

impl Running {
    /// Ask both listeners to stop, and wait for in-flight requests.
    pub async fn shutdown(self) -> Result<()> {
        let _ = self.stop.send(true);
        self.wait().await
    }
    /// Wait until both servers have stopped.
    pub async fn wait(self) -> Result<()> {
        for t in self.tasks {
            t.await.context("server task")??;
        }
        Ok(())
    }
    /// A handle that stops the server when sent `true`.
    pub fn stopper(&self) -> watch::Sender<bool> {
        self.stop.clone()
    }
}

/// Open the store (ingesting `cfg.ingest` first), bind both ports and serve.
pub async fn start(cfg: &ServeConfig) -> Result<Running> {
    cors_layer(&cfg.cors_origins)?;
    std::fs::create_dir_all(&cfg.data_dir)
        .with_context(|| format!("--data-dir {}", cfg.data_dir.display()))?;
    let location = match &cfg.store {
        Some(s) => crate::store::Location::parse(s).map_err(|e| anyhow::anyhow!("--store: {e}"))?,
        None => crate::store::Location::Sqlite(cfg.data_dir.join("choreo.db")),
    };
    let store = Store::open_at(&location, Some(&cfg.data_dir))
        .await
        .context("--store")?;
    tracing::info!("store: {}", store.label());
    if !cfg.ingest.is_empty() {
        let r =
            crate::search::ingest::ingest(&store, &cfg.ingest, &Default::default(), &|_, _, _| {})
                .await?;
        tracing::info!(
            "ingested {} motions ({} windows), {} already stored, {} unreadable",
            r.motions,
            r.windows,
            r.skipped,
            r.errors.len()
        );
    }
    if cfg.vector_dtype.is_half() && cfg.hnsw_backend == crate::index::hnsw::Backend::HnswRs {
        anyhow::bail!(
            "--vector-dtype {} needs --hnsw-backend flat (hnsw_rs stores f32 only)",
            cfg.vector_dtype.name()
        );
    }
    let searcher = Searcher::open(
        store.clone(),
        HnswParams {
            backend: cfg.hnsw_backend,
            dtype: cfg.vector_dtype,
            m: cfg.hnsw_m,
            ef_construction: cfg.hnsw_ef_construction,
            ..Default::default()
        },
    )
    .await?
    .with_channel_cache(cfg.channel_cache_mb << 20);
    let engine = crate::lm::engine::Engine::new(cfg.runtime, cfg.ort_lib.as_deref())?
        .with_local_step(cfg.local_step);
    tracing::info!("model runtime: {}", engine.runtime().name());
    let model = if cfg.model.exists() {
        let t0 = std::time::Instant::now();
        let m = crate::lm::model::MotionModel::load_with(&cfg.model, &engine)
            .with_context(|| format!("--model {}", cfg.model.display()))?;
        tracing::info!(
            "model {} ({}) loaded in {:.2} s; context {} frames; conditioned on: {}",
            cfg.model.display(),
            m.kind(),
            t0.elapsed().as_secs_f64(),
            m.context_frames(),
            m.cond_kinds().join(", ")
        );
        // The frame model's states are the `lm` search embedding.
        if let Ok(emb) = crate::lm::embed::LmEmbedder::new(&m) {
            searcher.set_lm(emb);
        }
        let ex = m
            .exemplars(&cfg.model)
            .with_context(|| format!("--model {}", cfg.model.display()))?;
        match &ex {
            Some(e) => tracing::info!(
                "{} style exemplars of {:.1} s: a generation with labels and no seed starts from one",
                e.len(),
                e.seconds
            ),
            None => tracing::info!("no {} beside the model: labels alone condition generation", crate::lm::exemplars::FILE),
        }
        Some((m, ex))
    } else {
        tracing::warn!(
            "no model at {}: generate and classify will answer 503 (set --model)",
            cfg.model.display()
        );
        None
    };
    let auth = Arc::new(
        crate::service::auth::Auth::new(&crate::service::auth::AuthConfig {
            token: cfg.token.clone(),
            tokens_file: cfg.tokens.clone(),
            public_read: cfg.public_read,
            rate_limit: cfg.rate_limit,
            rate_burst: cfg.rate_burst,
        })
        .map_err(|e| anyhow::anyhow!("--tokens / --token: {e}"))?,
    );
    if !auth.has_tokens() {
        if !cfg.public_read {
            anyhow::bail!(
                "no token and no --public-read: every request would be refused. Give --token \
                 (CHOREO_TOKEN) or --tokens FILE (CHOREO_TOKENS), or --public-read for an open archive"
            );
        }
        tracing::warn!("no --token / --tokens: reads are open (--public-read), ingest and delete are switched off");
    } else if cfg.public_read {
        tracing::warn!("--public-read: anyone who reaches the port can query, list and export every stored motion");
    }
    crate::service::auth::spawn_reloader(auth.clone(), store.clone());
    let inbetweener = if cfg.inbetweener.exists() {
        Some(Arc::new(
            crate::lm::inbetween::Inbetweener::load_with(&cfg.inbetweener, &engine)
                .with_context(|| format!("--inbetweener {}", cfg.inbetweener.display()))?,
        ))
    } else {
        tracing::warn!(
            "no in-betweener at {}: keyframes with inbetween=learned will answer 503",
            cfg.inbetweener.display()
        );
        None
    };
    let (model, exemplars) = match model {
        Some((m, ex)) => (Some(m), ex),
        None => (None, None),
    };
    let state = Arc::new(
        Choreo::new(store, searcher, cfg.workers, model, inbetweener, auth)
            .with_exemplars(exemplars),
    );
    state
        .searcher
        .spawn_maintenance(std::time::Duration::from_millis(500));
    if cfg.sync_ms > 0 {
        state
            .searcher
            .spawn_sync(std::time::Duration::from_millis(cfg.sync_ms));
    }
    let max = cfg.max_body_mb.max(1) << 20;
    let http_l = tokio::net::TcpListener::bind((cfg.bind.as_str(), cfg.http_port))
        .await
        .with_context(|| format!("--http-port {}", cfg.http_port))?;
    let grpc_l = tokio::net::TcpListener::bind((cfg.bind.as_str(), cfg.grpc_port))
        .await
        .with_context(|| format!("--grpc-port {}", cfg.grpc_port))?;
    let (http_addr, grpc_addr) = (http_l.local_addr()?, grpc_l.local_addr()?);
    let (stop, rx) = watch::channel(false);
    let stopped = |mut rx: watch::Receiver<bool>| async move {
        let _ = rx.wait_for(|v| *v).await;
    };
    let mut app = http::router(state.clone(), max);
    if let Some(cors) = cors_layer(&cfg.cors_origins)? {
        app = app.layer(cors);
    }
    let r1 = rx.clone();
    let t1 = tokio::spawn(async move {
        axum::serve(
            http_l,
            app.into_make_service_with_connect_info::<std::net::SocketAddr>(),
        )
        .with_graceful_shutdown(stopped(r1))
        .await
        .context("REST server")
    });
    let grpc_metrics = crate::service::metrics::GrpcMetricsLayer(state.metrics.clone());
    let svc = grpc::service(state, max);
    // Standard gRPC health (SERVING for "" and choreo.v1.Choreo) and
    // reflection (grpcurl works without the .proto file).
    let (health_reporter, health) = tonic_health::server::health_reporter();
    health_reporter
        .set_serving::<grpc::pb::choreo_server::ChoreoServer<grpc::ChoreoGrpc>>()
        .await;
    let reflection = tonic_reflection::server::Builder::configure()
        .register_encoded_file_descriptor_set(grpc::FILE_DESCRIPTOR_SET)
        .build_v1()
        .context("gRPC reflection")?;
    let r2 = rx.clone();
    let t2 = tokio::spawn(async move {
        tonic::transport::Server::builder()
            .layer(grpc_metrics)
            .add_service(health)
            .add_service(reflection)
            .add_service(svc)
            .serve_with_incoming_shutdown(
                tonic::transport::server::TcpIncoming::from(grpc_l),
                stopped(r2),
            )
            .await
            .context("gRPC server")
    });
    Ok(Running {
        http: http_addr,
        grpc: grpc_addr,
        stop,
        tasks: vec![t1, t2],
    })
}

/// Serve until SIGINT or SIGTERM.
pub async fn serve(cfg: ServeConfig) -> Result<()> {
    let running = start(&cfg).await?;
    tracing::info!(
        "choreo: REST on http://{}, gRPC on {}",
        running.http,
        running.grpc
    );
    let stop = running.stopper();
    tokio::spawn(async move {
        let ctrl_c = tokio::signal::ctrl_c();
        #[cfg(unix)]
        {
            let mut term =
                tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())
                    .expect("SIGTERM handler");
            tokio::select! {
                _ = ctrl_c => {},
                _ = term.recv() => {},
            }
        }
        #[cfg(not(unix))]
        let _ = ctrl_c.await;
        tracing::info!("choreo: shutting down");
        let _ = stop.send(true);
    });
    running.wait().await
}
