"""Calibration boards: ChArUco and chessboard specs, their TOML file, and OpenCV objects.

`board.toml` (this project's format, mm)::

    type = "charuco"          # or "chessboard"
    columns = 8               # squares across
    rows = 5                  # squares down
    square_mm = 25.0
    marker_mm = 18.75         # ChArUco only; default 0.75 x square
    dictionary = "DICT_4X4_50"
    inverted = false          # white-on-black board
    legacy = false            # OpenCV's pre-4.6 ChArUco pattern

Caliscope's `charuco.toml` is read as well (see `load_board`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np
import tomli_w

from .errors import SandtrackError
from .tomlfile import read_toml


@dataclass(frozen=True)
class BoardSpec:
    type: str = "charuco"
    columns: int = 8
    rows: int = 5
    square_mm: float = 25.0
    marker_mm: float | None = None
    dictionary: str = "DICT_4X4_50"
    inverted: bool = False
    legacy: bool = False

    def __post_init__(self) -> None:
        if self.type not in ("charuco", "chessboard"):
            raise SandtrackError(f"board type must be 'charuco' or 'chessboard', not {self.type!r}")
        if not all(isinstance(n, (int, np.integer)) and not isinstance(n, bool) for n in (self.columns, self.rows)):
            raise SandtrackError(f"board columns and rows must be whole numbers, not {self.columns!r}, {self.rows!r}")
        if self.columns < 3 or self.rows < 3:
            raise SandtrackError("a board needs at least 3 columns and 3 rows of squares")
        if not 0.01 <= self.square_mm <= 1e5:
            raise SandtrackError("board square size must be between 0.01 and 100000 mm")
        if self.type == "charuco" and not hasattr(cv2.aruco, self.dictionary):
            raise SandtrackError(f"unknown ArUco dictionary {self.dictionary!r}")
        # OpenCV builds the board in float32: the sizes must differ there too
        if self.marker_mm is not None and not (isinstance(self.marker_mm, (int, float, np.floating))
                                               and 0.01 <= np.float32(self.marker_mm) < np.float32(self.square_mm)):
            raise SandtrackError("marker size must be positive and smaller than the square")

    @property
    def marker_size_mm(self) -> float:
        return self.marker_mm if self.marker_mm is not None else 0.75 * self.square_mm

    @property
    def inner_corners(self) -> tuple[int, int]:
        """(across, down) count of inner chessboard corners."""
        return self.columns - 1, self.rows - 1

    @property
    def n_corners(self) -> int:
        a, d = self.inner_corners
        return a * d

    @property
    def size_mm(self) -> tuple[float, float]:
        return self.columns * self.square_mm, self.rows * self.square_mm

    def corner_points_mm(self) -> np.ndarray:
        """(n_corners, 3) inner corners in the board frame (mm), in OpenCV's ChArUco id order:
        id = row * (columns - 1) + col, x to the right, y down the board image, z = 0."""
        a, d = self.inner_corners
        ii, jj = np.meshgrid(np.arange(a), np.arange(d))
        pts = np.stack([(ii.ravel() + 1) * self.square_mm, (jj.ravel() + 1) * self.square_mm,
                        np.zeros(a * d)], axis=1)
        return pts.astype(np.float64)

    def aruco_dictionary(self):
        return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))

    def cv_board(self):
        """The OpenCV CharucoBoard (ChArUco boards only), in mm units."""
        if self.type != "charuco":
            raise SandtrackError("a chessboard has no ArUco markers")
        board = cv2.aruco.CharucoBoard(
            (self.columns, self.rows), float(self.square_mm), float(self.marker_size_mm),
            self.aruco_dictionary(),
        )
        board.setLegacyPattern(bool(self.legacy))
        return board

    def render(self, px_per_mm: float = 8.0, margin_mm: float = 0.0) -> np.ndarray:
        """Greyscale image of the board (uint8), `px_per_mm` pixels per mm, with a white margin."""
        w_mm, h_mm = self.size_mm
        w = int(round(w_mm * px_per_mm))
        h = int(round(h_mm * px_per_mm))
        if self.type == "charuco":
            img = self.cv_board().generateImage((w, h), marginSize=0, borderBits=1)
        else:
            yy, xx = np.mgrid[0:h, 0:w]
            cell = (xx / (self.square_mm * px_per_mm)).astype(int) + (yy / (self.square_mm * px_per_mm)).astype(int)
            img = np.where(cell % 2 == 0, 0, 255).astype(np.uint8)
        if self.inverted:
            img = 255 - img
        m = int(round(margin_mm * px_per_mm))
        if m:
            img = cv2.copyMakeBorder(img, m, m, m, m, cv2.BORDER_CONSTANT, value=0 if self.inverted else 255)
        return img

    def to_toml(self) -> str:
        d = {k: v for k, v in asdict(self).items() if v is not None}
        return tomli_w.dumps(d)

    def save(self, path: str | Path) -> None:
        Path(path).write_text(self.to_toml())

    def to_json_dict(self) -> dict:
        return asdict(self)


def board_from_dict(d: dict, source: str = "board") -> BoardSpec:
    """Our format, or Caliscope's charuco.toml (detected by its `square_size_override_cm` /
    `aruco_scale` keys)."""
    if not isinstance(d, dict):
        raise SandtrackError(f"{source}: malformed board (a table of settings was expected)")
    if "charuco" in d and isinstance(d["charuco"], dict):
        d = d["charuco"]
    try:
        if "square_size_override_cm" in d or "aruco_scale" in d or "board_height" in d:
            square_mm = float(d.get("square_size_override_cm", 0) or 0) * 10.0
            if square_mm <= 0:
                raise SandtrackError(f"{source}: Caliscope board without square_size_override_cm")
            return BoardSpec(
                type="charuco",
                columns=int(d["columns"]),
                rows=int(d["rows"]),
                square_mm=square_mm,
                marker_mm=square_mm * float(d.get("aruco_scale", 0.75)),
                dictionary=str(d.get("dictionary", "DICT_4X4_50")),
                inverted=bool(d.get("inverted", False)),
                legacy=bool(d.get("legacy_pattern", False)),
            )
        known = {"type", "columns", "rows", "square_mm", "marker_mm", "dictionary", "inverted", "legacy"}
        unknown = set(d) - known
        if unknown:
            raise SandtrackError(f"{source}: unknown board keys {sorted(unknown)}")
        return BoardSpec(**{k: d[k] for k in known if k in d})
    except (KeyError, TypeError, ValueError, OverflowError) as exc:
        raise SandtrackError(f"{source}: malformed board ({exc})") from None


def load_board(path: str | Path) -> BoardSpec:
    return board_from_dict(read_toml(path, "board"), source=str(path))
