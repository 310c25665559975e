-- How a motion's file is read back, and where it came from on video.
ALTER TABLE motions ADD COLUMN read_options TEXT;
ALTER TABLE motions ADD COLUMN video TEXT;
ALTER TABLE motions ADD COLUMN video_offset_s DOUBLE PRECISION;
