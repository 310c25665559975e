-- Collections: every motion belongs to one; tokens are granted per collection.
CREATE TABLE collections (
    name       TEXT PRIMARY KEY,
    created_at TEXT NOT NULL DEFAULT to_char(now() AT TIME ZONE 'UTC', 'YYYY-MM-DD"T"HH24:MI:SS.MS"Z"')
);
INSERT INTO collections (name) VALUES ('default');
ALTER TABLE motions ADD COLUMN collection TEXT NOT NULL DEFAULT 'default';
CREATE INDEX motions_collection ON motions(collection);
