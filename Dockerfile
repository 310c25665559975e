# choreo: the server image. Build: docker build -t choreo .
# Run:   docker run -p 8080:8080 -p 50051:50051 -e CHOREO_TOKEN=change-me \
#          -v choreo-data:/var/lib/choreo choreo
# The bundled models (models/) are licensed for non-commercial use
# (Bandai Namco data); see README "Model licence".

# The image runs either model runtime, built with the `onnxruntime` feature
# and the library of the onnxruntime wheel copied in below (ORT_DYLIB_PATH):
# `auto` (the default) takes onnxruntime, the faster of the two (README,
# "The model runtime"), and falls back to tract, saying why, where that
# library does not load; `-e CHOREO_RUNTIME=tract` or `=ort` pins one.

# --- onnxruntime's library, from the pip wheel ------------------------------
FROM python:3.11-slim-bookworm AS ortlib
RUN pip install --no-cache-dir onnxruntime==1.32.0 \
    && mkdir -p /opt/onnxruntime \
    && cp "$(python -c 'import onnxruntime, os; print(os.path.dirname(onnxruntime.__file__))')"/capi/libonnxruntime.so.1.32.0 /opt/onnxruntime/

# --- build -----------------------------------------------------------------
FROM rust:1.95-bookworm AS build
WORKDIR /src
# Dependencies first, so source edits do not rebuild them.
COPY Cargo.toml Cargo.lock build.rs ./
COPY proto proto
COPY migrations migrations
RUN mkdir -p src/bin/choreo-train && echo 'fn main() {}' > src/main.rs && touch src/lib.rs \
    && echo 'fn main() {}' > src/bin/choreo-train/main.rs \
    && cargo build --release --features onnxruntime --bin choreo || true
COPY src src
COPY openapi.json openapi.json
# The web studio's built assets, embedded by src/api/studio.rs.
COPY web/dist web/dist
RUN touch src/main.rs src/lib.rs && cargo build --release --locked --features onnxruntime --bin choreo \
    && strip target/release/choreo

# --- run -------------------------------------------------------------------
FROM debian:bookworm-slim
RUN apt-get update && apt-get install -y --no-install-recommends ca-certificates libstdc++6 \
    && rm -rf /var/lib/apt/lists/* \
    && useradd --system --uid 10001 --home-dir /var/lib/choreo --shell /usr/sbin/nologin choreo \
    && mkdir -p /var/lib/choreo && chown choreo:choreo /var/lib/choreo
COPY --from=build /src/target/release/choreo /usr/local/bin/choreo
COPY --from=ortlib /opt/onnxruntime /opt/onnxruntime
COPY models /opt/choreo/models
USER 10001:10001
ENV CHOREO_DATA_DIR=/var/lib/choreo \
    CHOREO_BIND=0.0.0.0 \
    CHOREO_HTTP_PORT=8080 \
    CHOREO_GRPC_PORT=50051 \
    CHOREO_MODEL=/opt/choreo/models/default \
    CHOREO_INBETWEENER=/opt/choreo/models/inbetween \
    CHOREO_RUNTIME=auto \
    ORT_DYLIB_PATH=/opt/onnxruntime/libonnxruntime.so.1.32.0
VOLUME /var/lib/choreo
EXPOSE 8080 50051
ENTRYPOINT ["/usr/local/bin/choreo"]
CMD ["serve"]
