-- The bytes a motion was ingested from, when the store keeps them.
CREATE TABLE motion_files (
    motion_id BIGINT PRIMARY KEY REFERENCES motions(id) ON DELETE CASCADE,
    name      TEXT   NOT NULL,
    bytes     BYTEA  NOT NULL
);
