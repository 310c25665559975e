-- Collections: every motion belongs to one (a company's archive, one
-- production); tokens are granted per collection. `default` keeps the
-- behaviour from before collections.
CREATE TABLE collections (
    name       TEXT PRIMARY KEY,
    created_at TEXT NOT NULL DEFAULT (strftime('%Y-%m-%dT%H:%M:%fZ', 'now'))
);
INSERT INTO collections (name) VALUES ('default');
ALTER TABLE motions ADD COLUMN collection TEXT NOT NULL DEFAULT 'default';
CREATE INDEX motions_collection ON motions(collection);
