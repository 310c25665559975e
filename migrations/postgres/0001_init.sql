-- choreo's store on PostgreSQL: the same tables as migrations/sqlite, in
-- PostgreSQL's types (BIGINT ids, DOUBLE PRECISION, BYTEA). Several
-- `choreo serve` replicas share it; each builds its own indexes from it.

CREATE TABLE motions (
    id            BIGINT           PRIMARY KEY,
    source_path   TEXT             NOT NULL,
    content_hash  TEXT             NOT NULL UNIQUE,   -- sha256 of the collection and the file's bytes
    format        TEXT             NOT NULL,
    fps           DOUBLE PRECISION NOT NULL,
    frames        BIGINT           NOT NULL,
    joints        BIGINT           NOT NULL,
    skeleton      TEXT             NOT NULL,
    duration_s    DOUBLE PRECISION NOT NULL,
    labels        TEXT             NOT NULL,          -- JSON object
    ingested_at   TEXT             NOT NULL DEFAULT to_char(now() AT TIME ZONE 'UTC', 'YYYY-MM-DD"T"HH24:MI:SS.MS"Z"')
);

CREATE TABLE motion_labels (
    motion_id BIGINT NOT NULL REFERENCES motions(id) ON DELETE CASCADE,
    kind      TEXT   NOT NULL,
    value     TEXT   NOT NULL,
    PRIMARY KEY (motion_id, kind)
);
CREATE INDEX motion_labels_kind_value ON motion_labels(kind, value);

CREATE TABLE motion_channels (
    motion_id BIGINT           PRIMARY KEY REFERENCES motions(id) ON DELETE CASCADE,
    fps       DOUBLE PRECISION NOT NULL,
    frames    BIGINT           NOT NULL,
    data      BYTEA            NOT NULL
);

CREATE TABLE windows (
    id          BIGSERIAL PRIMARY KEY,
    motion_id   BIGINT    NOT NULL REFERENCES motions(id) ON DELETE CASCADE,
    start_frame BIGINT    NOT NULL,
    frames      BIGINT    NOT NULL,
    UNIQUE (motion_id, start_frame)
);

CREATE TABLE embeddings (
    window_id BIGINT NOT NULL REFERENCES windows(id) ON DELETE CASCADE,
    kind      TEXT   NOT NULL,
    dim       BIGINT NOT NULL,
    vector    BYTEA  NOT NULL,
    PRIMARY KEY (kind, window_id)
);
-- A replica catching up reads one motion's embeddings by its windows.
CREATE INDEX embeddings_window ON embeddings(window_id);
CREATE INDEX windows_motion ON windows(motion_id);

CREATE TABLE models (
    name       TEXT   PRIMARY KEY,
    generation BIGINT NOT NULL,
    body       TEXT   NOT NULL
);

CREATE TABLE meta (
    key   TEXT PRIMARY KEY,
    value TEXT NOT NULL
);
INSERT INTO meta (key, value) VALUES ('generation', '0'), ('feature_version', '1');
