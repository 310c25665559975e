-- The bytes a motion was ingested from, when the store keeps them (uploads
-- through the API; `choreo ingest --keep-files`). With them the store holds
-- the whole motion (skeleton, translation, the source's own frame rate), so
-- `get` and `export` need nothing outside the database. Motions ingested
-- without them are read back from `motions.source_path` (checked against
-- `content_hash`).
CREATE TABLE motion_files (
    motion_id INTEGER PRIMARY KEY REFERENCES motions(id) ON DELETE CASCADE,
    name      TEXT    NOT NULL,              -- the file name the format is detected by
    bytes     BLOB    NOT NULL
);
