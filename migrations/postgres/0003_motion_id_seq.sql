-- Motion ids are never reused, and replicas inserting at once never take
-- the same one: a sequence (a failed insert leaves a gap, never a repeat).
CREATE SEQUENCE motion_ids;
SELECT setval('motion_ids', COALESCE((SELECT MAX(id) FROM motions), 0) + 1, false);
