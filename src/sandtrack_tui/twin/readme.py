"""The README.md written next to a rendered sample (documents every file and column)."""

from __future__ import annotations

TEMPLATE = """# Sample project: rendered twin of the sand-box rig

Rendered by `sandtrack sample {out_name} --seed {seed} --preset {preset}` (deterministic: the same seed gives
identical ground-truth files and videos that decode to identical frames). Nothing here was filmed: the rig is
ray-cast through the true camera models (distortion included), so every figure below is exact.

## The rig
- Sand box 1500 x 500 x 500 mm (L x W x H), sand surface at Y = 240 mm.
- **World frame (mm)**: origin at the box's inner corner at floor level; **X** across the box width (0..500),
  **Y** up (gravity -Y), **Z** along the box length and the tool's travel (0..1500).
- Tool: chisel with wings (1:2), working depth {tool_depth:g} mm, shank centred on X = {tool_x:g} mm, pulled along
  +Z at {tool_speed:g} mm/s over {tool_travel:g} mm (shank front from Z = {tool_z0:g} to {tool_z1:g} mm), moving
  from scene time {tool_start:g} s to {tool_end:g} s. Only its 12 mm-thick steel shank is above the sand.
- 8 blue markers (5 mm wooden beads), ids 1-4 on the tool path (X = 250) at Z = 500, 550, 600, 650 mm, ids 5-8
  50 mm aside (X = 300) at the same Z. The tool pushes them ahead and aside, lifts and rolls them; some are
  buried or hidden behind the shank for a while and reappear.
- Two GoPro-like cameras, 1920 x 1080, {fps:g} fps, H.264 (libx264) + AAC mono 48 kHz. **side** looks at the
  surface from above the side wall at X = 0 (its image x runs along +Z); **front** looks back along -Z from
  above the front end. Intrinsics and distortion as in the study (front: k1 0.01, k2 -0.01, p2 -0.01).
  Markers measure about 9.5-10.5 px (side) and 7.5-9.5 px (front).

## Files
- `board.toml`: the ChArUco board (project board format): 8 x 5 squares of 25 mm, 18.75 mm markers,
  DICT_4X4_50.
- `calibration/side.mp4`, `calibration/front.mp4`: the board moved by hand, {cal_frames} frames each; flat on the
  sand first (reference pose), then lifted, tilted up to ~60 deg, near and far, sometimes partly out of view,
  motion blur when fast.
- `calibration/reference.toml`: `frame` (a frame index showing the flat reference pose in both calibration
  videos), `origin_mm` (world position of the board-frame origin in that pose), `board_axes_in_world`.
- `experiment/side.mp4`, `experiment/front.mp4`: the tool's pass, {exp_frames} frames each.
- `ground_truth/cameras.toml`: the true rig in the project's calibration format (`Calibration.load`): rig frame
  = side camera frame (side rotation = translation = 0), `world_from_rig` = the true 4 x 4 rig -> world transform.
- `ground_truth/sync.json`: true offsets and clap times (see Sync).
- `ground_truth/markers_side.csv`, `markers_front.csv`: per frame of THAT camera and marker:
  `frame, time_s, scene_time_s, marker, X_mm, Y_mm, Z_mm, x_px, y_px, visible, visible_fraction`.
- `ground_truth/trajectories.csv`: per side frame and marker:
  `frame, time_s, marker, X_mm, Y_mm, Z_mm, visible_side, visible_front` (front visibility at the same instant).
- `ground_truth/tool.csv`: per side frame: `frame, time_s, scene_time_s, tool_X_mm, tool_Z_mm` (front face of
  the shank), `depth_mm, speed_mm_s`.
- `ground_truth/calibration_corners_side.csv`, `calibration_corners_front.csv`: every board corner visible in
  each calibration frame of that camera: `frame, corner_id, x_px, y_px, X_mm, Y_mm, Z_mm` (corner_id = OpenCV
  ChArUco id; XYZ in the world frame). Visible = inside the image and on the printed side, less than 80 deg off.
- `ground_truth/calibration_board_poses.csv`: per camera and calibration frame:
  `camera, frame, time_s, scene_time_s, rx, ry, rz` (Rodrigues) and `tx_mm, ty_mm, tz_mm` of world_from_board
  (X_world = R X_board + t), `blur_samples` (poses averaged within the 1/200 s exposure), `blur_px` (largest
  corner motion during the exposure).
- `ground_truth/scene.json`: box, camera centres, tool, marker radius, visibility rule.
- `dem/particles.csv`: "model" trajectories in the DEM exchange format `particle_id, time_s, x, y, z` (mm, world
  axes and origin; time_s = 0 when the tool starts), {dem_rate:g} Hz.
- `dem/differences.json`: exactly how the model differs from the truth (time shift, drifting particles).

Columns: `frame` is that video's own frame index (0-based); `time_s` = frame / fps = the frame's presentation time
in its file (both files start at pts 0); `scene_time_s` = time on the common clock (side start = 0).
`x_px, y_px` = true pixel of the marker's centre (OpenCV convention: pixel centres at integer coordinates,
distortion applied), also given when the marker is hidden. `visible` = 1 when at least half of the marker's
silhouette is really seen (inside the image, not behind the shank, not under or behind sand);
`visible_fraction` gives that fraction.

## Sync
- Experiment: `offset_s` = **{offset:.4f} s** (not a whole number of frames): the front camera started recording
  that much later than the side camera, so an event at side time t appears at front time t - offset_s.
  The clap is at side time {clap_side:.4f} s and front time {clap_front:.4f} s.
- Both video tracks start at pts 0. The side audio starts at 0 s; the **front experiment's audio track starts at
  {front_audio:.3f} s** (use presentation timestamps, not sample indices). No acoustic path delay is modelled:
  the audio offset equals the video clock offset. AAC adds its usual encoder priming, handled by the pts.
- Calibration session: the front camera started {cal_offset_frames} frames ({cal_offset:.2f} s) later, so
  side frame i and front frame i - {cal_offset_frames} show the same instant; its clap is at side time
  {clap_side_cal:.2f} s.
- Sound: shared room noise, mains hum, the tool's drive while it moves, a hand clap; each camera adds its own
  microphone colouring and noise.

## Calibration reference (world frame)
In `calibration/reference.toml` frame {ref_frame} (both videos) the board lies flat on the sand, printed face up:
board x (columns) along world +X, board y (rows) along world +Z, board z = world -Y, board origin (the corner
of the board frame, BoardSpec coordinates (0, 0, 0)) at world {ref_origin} mm (the face is 3 mm above the sand).
So world = R_ref @ board + origin with R_ref = [[1,0,0],[0,0,-1],[0,1,0]].

## DEM model file
`dem(t) = truth(t - {dem_shift:g} s) + drift * t`: the model runs {dem_shift:g} s late; particles
{drifting} drift linearly ({drift_text}); the others are exact. `truth(t)` is the trajectory at side time
{tool_start:g} + t s.

## Figures
- Experiment: {exp_frames} frames per camera; calibration: {cal_frames} frames per camera;
  {two_view} two-view corner observations (corner seen by both cameras at the same instant).
"""


def readme_text(**info) -> str:
    return TEMPLATE.format(**info)
