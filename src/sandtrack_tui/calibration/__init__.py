"""Camera calibration: board detection, intrinsics, bundle adjustment, world frame, calibration points,
calibration from known points, and Caliscope import/export."""
