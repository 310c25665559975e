-- How a motion's file is read back, and where it came from on video.
-- read_options: the reader's options as JSON (keypoint layout, frame rate,
-- up axis, confidence threshold, BVH scale); NULL means the defaults. Without
-- them a stored keypoint file could not be parsed again.
ALTER TABLE motions ADD COLUMN read_options TEXT;
-- The footage a motion was estimated from (a path or URL, as given), and the
-- video time of the motion's first frame in seconds.
ALTER TABLE motions ADD COLUMN video TEXT;
ALTER TABLE motions ADD COLUMN video_offset_s REAL;
