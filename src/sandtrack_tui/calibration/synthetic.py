"""Synthetic board images through known cameras: exact answers for tests and benchmarks.

Every output pixel is undistorted to a ray (once per camera), the ray meets the board plane of
each pose, and the board texture (BoardSpec.render with a white margin) is sampled there.
"""

from __future__ import annotations

import cv2
import numpy as np

from ..board import BoardSpec
from ..camera import Calibration, Camera
from .geometry import from_T, inv_T, to_T

PX_PER_MM = 4.0


def board_texture(board: BoardSpec, margin_mm: float | None = None) -> tuple[np.ndarray, float]:
    margin = board.square_mm * 0.6 if margin_mm is None else margin_mm
    tex = board.render(px_per_mm=PX_PER_MM, margin_mm=margin)
    # light blur against aliasing when the board is minified; symmetric, so corners stay put
    return cv2.GaussianBlur(tex, (0, 0), 1.5), margin


def _rays(cam: Camera) -> np.ndarray:
    """(H, W, 3) unit-depth rays of every pixel centre in the camera frame."""
    xx, yy = np.meshgrid(np.arange(cam.width, dtype=np.float64), np.arange(cam.height, dtype=np.float64))
    px = np.stack([xx.ravel(), yy.ravel()], axis=1).reshape(-1, 1, 2)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-12)
    if cam.model == "fisheye":
        n = cv2.fisheye.undistortPoints(px, cam.matrix, cam.distortion, criteria=crit)
    else:
        n = cv2.undistortPoints(px, cam.matrix, cam.distortion, criteria=crit)
    n = n.reshape(cam.height, cam.width, 2)
    return np.concatenate([n, np.ones((cam.height, cam.width, 1))], axis=2)


def render(cam: Camera, board: BoardSpec, T_rig_board: list[np.ndarray], noise: float = 1.5, seed: int = 0,
           background: int = 110) -> list[np.ndarray]:
    """Greyscale images of the board at the given board -> rig poses, seen by `cam`."""
    tex, margin = board_texture(board)
    rays = _rays(cam)
    T_cam_rig = to_T(cam.rvec, cam.tvec)
    rng = np.random.default_rng(seed)
    out = []
    rays2 = np.ascontiguousarray(rays[..., :2].astype(np.float32))
    for T in T_rig_board:
        Tcb = T_cam_rig @ T
        # a plane maps to normalised image coordinates by the homography [r1 r2 t]; invert it per pixel
        H = np.column_stack([Tcb[:3, 0], Tcb[:3, 1], Tcb[:3, 3]])
        A = np.diag([PX_PER_MM, PX_PER_MM, 1.0])
        A[:2, 2] = margin * PX_PER_MM - 0.5
        M = A @ np.linalg.inv(H)
        tex_xy = cv2.perspectiveTransform(rays2, M)
        mapx = np.ascontiguousarray(tex_xy[..., 0])
        mapy = np.ascontiguousarray(tex_xy[..., 1])
        img = cv2.remap(tex, mapx, mapy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=background)
        if noise:
            img = cv2.add(img.astype(np.float32), rng.standard_normal(img.shape, dtype=np.float32) * noise)
        out.append(np.clip(img, 0, 255).astype(np.uint8))
    return out


def look_at(eye: np.ndarray, target: np.ndarray, up=(0.0, -1.0, 0.0)) -> np.ndarray:
    """T_cam_world for a camera at `eye` looking at `target` (OpenCV axes: z forward, y down)."""
    z = np.asarray(target, float) - np.asarray(eye, float)
    z /= np.linalg.norm(z)
    x = np.cross(np.asarray(up, float), z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = -R @ np.asarray(eye, float)
    return T


def stereo_rig(size=(960, 540), focal=(820.0, 760.0), baseline_mm=420.0, distance_mm=700.0,
               dist=((-0.12, 0.05, 0.0004, -0.0003, 0.0), (0.08, -0.06, -0.0005, 0.0002, 0.0))) -> Calibration:
    """Two converging cameras ('side', 'front') watching a point `distance_mm` ahead; rig = side."""
    w, h = size
    target = np.array([0.0, 0.0, distance_mm])
    eyes = [np.array([0.0, 0.0, 0.0]), np.array([baseline_mm, -60.0, 90.0])]
    T0 = look_at(eyes[0], target)
    cams = {}
    for i, name in enumerate(("side", "front")):
        Tc = look_at(eyes[i], target) @ inv_T(T0)
        r, t = from_T(Tc)
        K = np.array([[focal[i], 0, w / 2 + 7.3 * (1 - 2 * i)], [0, focal[i] * 1.001, h / 2 - 4.1], [0, 0, 1]])
        cams[name] = Camera(name=name, width=w, height=h, matrix=K, distortion=np.array(dist[i]), rvec=r, tvec=t)
    return Calibration(cameras=cams)


def board_poses(n: int, board: BoardSpec, distance_mm: float = 700.0, spread_mm=(220.0, 120.0, 160.0),
                max_tilt_deg: float = 40.0, seed: int = 0, target=None) -> list[np.ndarray]:
    """Random board -> rig poses around a point ahead of the rig, facing it, tilted up to max_tilt."""
    rng = np.random.default_rng(seed)
    w, h = board.size_mm
    centre = np.array([0.0, 0.0, distance_mm]) if target is None else np.asarray(target, float)
    out = []
    for _ in range(n):
        c = centre + rng.uniform(-1, 1, 3) * np.asarray(spread_mm)
        tilt = np.radians(rng.uniform(5, max_tilt_deg))
        axis_angle = rng.uniform(0, 2 * np.pi)
        axis = np.array([np.cos(axis_angle), np.sin(axis_angle), 0.0])
        spin = np.radians(rng.uniform(-15, 15))
        R = cv2.Rodrigues(axis * tilt)[0] @ cv2.Rodrigues(np.array([0, 0, spin]))[0]
        # board faces the origin: board z points away from the cameras (+z of the rig)
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = c - R @ np.array([w / 2, h / 2, 0.0])
        out.append(T)
    return out


def write_session(folder, n_views: int = 24, board: BoardSpec | None = None, seed: int = 0,
                  size=(960, 540), flat_reference: bool = True, video_fps: float | None = None) -> dict:
    """Render a two-camera board session into `folder`/side and `folder`/front (PNG image folders).

    With `flat_reference`, frame 0 shows the board lying flat (world convention of world.py) at
    origin (0, 0, 0). Returns {"truth": Calibration (world_from_rig set when flat_reference),
    "poses": board -> rig poses, "board": BoardSpec, "videos": {name: folder}}. With `video_fps`, each
    camera is written as an H.264 `NAME.mp4` instead of an image folder."""
    from pathlib import Path

    from .world import world_from_board_pose

    board = board or BoardSpec(columns=8, rows=5, square_mm=30.0, dictionary="DICT_4X4_50")
    scale = size[0] / 960.0
    truth = stereo_rig(size=size, focal=(820.0 * scale, 760.0 * scale))
    poses = board_poses(n_views, board, seed=seed)
    if flat_reference:
        # board lying flat below the rig: its normal (board z) points down = rig +y (cameras look along +z)
        T = np.eye(4)
        T[:3, :3] = cv2.Rodrigues(np.array([np.radians(-55.0), 0.0, 0.0]))[0]
        w, h = board.size_mm
        T[:3, 3] = np.array([0.0, 120.0, 720.0]) - T[:3, :3] @ np.array([w / 2, h / 2, 0.0])
        poses[0] = T
        truth.world_from_rig = world_from_board_pose(T)
    folder = Path(folder)
    videos = {}
    for i, (name, cam) in enumerate(truth.cameras.items()):
        images = render(cam, board, poses, seed=seed * 10 + i)
        if video_fps:
            videos[name] = str(folder / f"{name}.mp4")
            _write_mp4(videos[name], images, video_fps)
            continue
        d = folder / name
        d.mkdir(parents=True, exist_ok=True)
        for f, img in enumerate(images):
            cv2.imwrite(str(d / f"{f:05d}.png"), img)
        videos[name] = str(d)
    return {"truth": truth, "poses": poses, "board": board, "videos": videos}


def _write_mp4(path, images: list[np.ndarray], fps: float) -> None:
    import av

    with av.open(str(path), "w") as container:
        stream = container.add_stream("libx264", rate=int(round(fps)))
        stream.height, stream.width = images[0].shape[:2]
        stream.pix_fmt = "yuv420p"
        stream.options = {"crf": "14", "preset": "veryfast"}
        for img in images:
            for packet in stream.encode(av.VideoFrame.from_ndarray(img, format="gray")):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
