-- choreo's store: the source of truth for motions, their windows and the
-- window embeddings. Indexes on disk are rebuilt from it.

CREATE TABLE motions (
    id            INTEGER PRIMARY KEY,
    source_path   TEXT    NOT NULL,
    content_hash  TEXT    NOT NULL UNIQUE,   -- sha256 of the file's bytes
    format        TEXT    NOT NULL,          -- aist | amass | bvh
    fps           REAL    NOT NULL,          -- of the source file
    frames        INTEGER NOT NULL,          -- of the source file
    joints        INTEGER NOT NULL,
    skeleton      TEXT    NOT NULL,          -- smpl24 | smpl13 | custom
    duration_s    REAL    NOT NULL,
    labels        TEXT    NOT NULL,          -- JSON object
    ingested_at   TEXT    NOT NULL DEFAULT (strftime('%Y-%m-%dT%H:%M:%fZ', 'now'))
);

-- One row per label, for filtering.
CREATE TABLE motion_labels (
    motion_id INTEGER NOT NULL REFERENCES motions(id) ON DELETE CASCADE,
    kind      TEXT    NOT NULL,
    value     TEXT    NOT NULL,
    PRIMARY KEY (motion_id, kind)
);
CREATE INDEX motion_labels_kind_value ON motion_labels(kind, value);

-- The canonical channel matrix the windows are cut from: SMPL-24 axis-angle
-- at 60 fps, [frames][72] little-endian f32.
CREATE TABLE motion_channels (
    motion_id INTEGER PRIMARY KEY REFERENCES motions(id) ON DELETE CASCADE,
    fps       REAL    NOT NULL,
    frames    INTEGER NOT NULL,
    data      BLOB    NOT NULL
);

CREATE TABLE windows (
    id          INTEGER PRIMARY KEY,
    motion_id   INTEGER NOT NULL REFERENCES motions(id) ON DELETE CASCADE,
    start_frame INTEGER NOT NULL,            -- at 60 fps
    frames      INTEGER NOT NULL,
    UNIQUE (motion_id, start_frame)
);

CREATE TABLE embeddings (
    window_id INTEGER NOT NULL REFERENCES windows(id) ON DELETE CASCADE,
    kind      TEXT    NOT NULL,              -- stft | dct | pca
    dim       INTEGER NOT NULL,
    vector    BLOB    NOT NULL,              -- little-endian f32
    PRIMARY KEY (kind, window_id)
);

-- Fitted models (the PCA basis) as JSON.
CREATE TABLE models (
    name       TEXT    PRIMARY KEY,
    generation INTEGER NOT NULL,             -- store generation it was fitted at
    body       TEXT    NOT NULL
);

-- generation: bumped by every committed change, so indexes know when stale.
CREATE TABLE meta (
    key   TEXT PRIMARY KEY,
    value TEXT NOT NULL
);
INSERT INTO meta (key, value) VALUES ('generation', '0'), ('feature_version', '1');
