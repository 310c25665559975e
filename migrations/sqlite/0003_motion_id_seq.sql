-- Motion ids are never reused. SQLite's INTEGER PRIMARY KEY hands out
-- max(id) + 1, so deleting the newest motion would give its id to the next
-- one and an old link would silently point at another dance. The highest id
-- ever given is kept here; inserts take the next one.
CREATE TABLE motion_id_seq (
    last INTEGER NOT NULL
);
INSERT INTO motion_id_seq (last) SELECT COALESCE(MAX(id), 0) FROM motions;
CREATE TRIGGER motion_id_seq_advance AFTER INSERT ON motions BEGIN
    UPDATE motion_id_seq SET last = MAX(last, NEW.id);
END;
