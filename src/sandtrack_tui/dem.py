"""DEM particle trajectories: the exchange CSV and LIGGGHTS/LAMMPS ``dump custom`` files.

Everything is returned as a DataFrame ``particle_id, time_s, X_mm, Y_mm, Z_mm`` in the rig's world
frame (mm, s), sorted by particle and time.

Exchange CSV
    ``particle_id, time_s, x, y, z``: one row per particle and output time. Units of x, y, z:
    ``units`` (m, cm, mm); columns named ``x_mm``/``x_m`` carry their unit in the name. Without
    either, the unit is guessed from the extent of the positions (a sand bin spans well under 20 m
    and well over 20 mm): extent above 20 -> mm, else m; the guess is kept in ``df.attrs`` (and
    the CLI says so): give the unit to be sure. ``axes`` maps DEM axes to the rig's: ``"x,y,z"`` (identity),
    ``"x,-z,y"`` (rig X = DEM x, rig Y = -DEM z, rig Z = DEM y), ...; ``offset_mm`` is then added
    (the DEM origin in rig coordinates), and ``time_offset_s`` to the times.

LIGGGHTS / LAMMPS ``dump custom``
    Blocks ``ITEM: TIMESTEP``, optionally ``ITEM: TIME``, ``ITEM: NUMBER OF ATOMS``,
    ``ITEM: BOX BOUNDS``, ``ITEM: ATOMS id type x y z ...`` (rows unsorted unless ``dump_modify
    sort id``). Positions from x/y/z, xu/yu/zu, or scaled xs/ys/zs (mapped through the box bounds).
    Time = ``ITEM: TIME`` when present, else step x ``dt`` (``dt`` must then be given). Units as
    for the CSV (LIGGGHTS writes SI: metres; without ``units`` the same guess applies). One file
    with many blocks, or one file per step (give several paths or a glob); ``.gz`` is read too.

Exporting from DEM codes (short snippets, run inside the tool)
    Ansys Rocky, PrePost scripting (Python shell; Rocky writes SI: use units "m")::

        study = app.GetStudy()
        particles = study.GetParticles()
        gf = {k: particles.GetGridFunction(k) for k in
              ("Particle ID", "Coordinate : X", "Coordinate : Y", "Coordinate : Z")}
        with open("particles.csv", "w") as fh:
            fh.write("particle_id,time_s,x,y,z\\n")
            for k, t in enumerate(study.GetTimeSet()):
                ids, x, y, z = (g.GetArray(time_step=k) for g in gf.values())
                for row in zip(ids, x, y, z):
                    fh.write(f"{int(row[0])},{t},{row[1]},{row[2]},{row[3]}\\n")

    (older Rocky releases name the coordinates "Particle X-Coordinate", ...)

    Altair EDEM, with EDEMpy (SI: units "m")::

        from edempy import Deck
        deck = Deck("simulation.dem")
        with open("particles.csv", "w") as fh:
            fh.write("particle_id,time_s,x,y,z\\n")
            for k, t in enumerate(deck.timestepValues):
                p = deck.timestep[k].particle[0]          # particle type 0
                for i, (x, y, z) in zip(p.getIds(), p.getPositions()):
                    fh.write(f"{i},{t},{x},{y},{z}\\n")

    LIGGGHTS / LAMMPS input::

        dump  tracers tracer_group custom 200 dump.tracers id type x y z
        dump_modify tracers sort id

    (Names follow the vendors' scripting APIs; check the manual of the release at hand.)
"""

from __future__ import annotations

import glob
import gzip
import io
import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from .errors import SandtrackError

DEM_COLUMNS = ["particle_id", "time_s", "X_mm", "Y_mm", "Z_mm"]
UNIT_TO_MM = {"m": 1000.0, "cm": 10.0, "mm": 1.0, "um": 1e-3}
MAX_ABS_MM = 1e7  # 10 km: anything larger is a unit mistake


def parse_axes(spec: str) -> tuple[np.ndarray, np.ndarray]:
    """"x,-z,y" -> (source index per rig axis, sign per rig axis)."""
    parts = [p.strip().lower() for p in str(spec).split(",")]
    if len(parts) != 3:
        raise SandtrackError(f"axis mapping {spec!r}: give three comma-separated axes like x,-z,y")
    idx, sign = [], []
    for p in parts:
        m = re.fullmatch(r"([+-]?)([xyz])", p)
        if not m:
            raise SandtrackError(f"axis mapping {spec!r}: {p!r} is not one of x, y, z with an optional sign")
        sign.append(-1.0 if m.group(1) == "-" else 1.0)
        idx.append("xyz".index(m.group(2)))
    if sorted(idx) != [0, 1, 2]:
        raise SandtrackError(f"axis mapping {spec!r}: each of x, y, z must appear once")
    return np.array(idx), np.array(sign)


GUESS_EXTENT = 20.0


def guess_units(xyz: np.ndarray) -> str:
    """"mm" when the positions span more than GUESS_EXTENT (in their own unit), else "m"."""
    v = np.asarray(xyz, float).reshape(-1, 3)
    v = v[np.isfinite(v).all(axis=1)]
    if len(v) == 0:
        return "m"
    return "mm" if float((v.max(axis=0) - v.min(axis=0)).max()) > GUESS_EXTENT else "m"


def to_rig(particle_id, time_s, xyz, units: str | None = "m", axes: str = "x,y,z",
           offset_mm: Sequence[float] = (0.0, 0.0, 0.0), time_offset_s: float = 0.0, source: str = "",
           extra: dict | None = None) -> pd.DataFrame:
    """Scale, permute/flip axes and shift DEM positions into the tidy DEM table (mm, rig frame).
    units None: guessed (see module docstring), recorded in ``df.attrs["units_guessed"]``.
    `extra`: more per-row columns to carry (a ``radius`` is scaled to mm like the positions)."""
    guessed = None
    if units is None:
        units = guessed = guess_units(xyz)
    if units not in UNIT_TO_MM:
        raise SandtrackError(f"unknown length unit {units!r} (one of {', '.join(UNIT_TO_MM)})")
    idx, sign = parse_axes(axes)
    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3) * UNIT_TO_MM[units]
    xyz = xyz[:, idx] * sign + np.asarray(offset_mm, dtype=np.float64)
    t = np.asarray(time_s, dtype=np.float64) + float(time_offset_s)
    df = pd.DataFrame({"particle_id": np.asarray(particle_id).astype(np.int64), "time_s": t,
                       "X_mm": xyz[:, 0], "Y_mm": xyz[:, 1], "Z_mm": xyz[:, 2]})
    for name, values in (extra or {}).items():
        v = np.asarray(values, dtype=np.float64)
        df["radius_mm" if name == "radius" else name] = v * UNIT_TO_MM[units] if name == "radius" else v
    df = _validate(df, source)
    df.attrs["units"] = units
    if guessed:
        df.attrs["units_guessed"] = guessed
    return df


def _validate(df: pd.DataFrame, source: str) -> pd.DataFrame:
    where = f"{source}: " if source else ""
    if df.empty:
        raise SandtrackError(f"{where}no particle positions")
    finite = np.isfinite(df[["time_s", "X_mm", "Y_mm", "Z_mm"]].to_numpy()).all(axis=1)
    if not finite.any():
        raise SandtrackError(f"{where}no row has finite time and position")
    df = df[finite]
    big = np.abs(df[["X_mm", "Y_mm", "Z_mm"]].to_numpy()).max()
    if big > MAX_ABS_MM:
        raise SandtrackError(f"{where}positions up to {big:.3g} mm: wrong length unit?")
    if df.duplicated(["particle_id", "time_s"]).any():
        raise SandtrackError(f"{where}a particle appears twice at the same time")
    return df.sort_values(["particle_id", "time_s"], kind="stable").reset_index(drop=True)


def read_exchange_csv(path: str | Path, units: str | None = None, axes: str = "x,y,z",
                      offset_mm: Sequence[float] = (0.0, 0.0, 0.0), time_offset_s: float = 0.0,
                      extra: Sequence[str] = ()) -> pd.DataFrame:
    """The exchange CSV (see module docstring). `units` None: from column names (x_mm), else guessed.
    `extra`: further numeric columns to keep when the file has them (e.g. "type", "radius")."""
    p = Path(path)
    if not p.is_file():
        raise SandtrackError(f"file not found: {p}")
    try:
        df = pd.read_csv(p, skipinitialspace=True)
    except pd.errors.EmptyDataError:
        raise SandtrackError(f"{p}: empty file") from None
    except (pd.errors.ParserError, UnicodeDecodeError, ValueError) as exc:
        raise SandtrackError(f"{p}: not a readable CSV ({str(exc).splitlines()[0][:120]})") from None
    cols = {str(c).strip().lower(): c for c in df.columns}
    pos, found_unit = [], None
    for ax in "xyz":
        for name in (ax, *(f"{ax}_{u}" for u in UNIT_TO_MM)):
            if name in cols:
                pos.append(cols[name])
                if "_" in name:
                    found_unit = name.split("_", 1)[1]
                break
    tcol = next((cols[n] for n in ("time_s", "time", "t") if n in cols), None)
    idcol = next((cols[n] for n in ("particle_id", "id", "particle") if n in cols), None)
    if len(pos) != 3 or tcol is None or idcol is None:
        raise SandtrackError(f"{p}: expected columns particle_id, time_s, x, y, z (found: "
                             f"{', '.join(map(str, df.columns[:8]))})")
    if df.empty:
        raise SandtrackError(f"{p}: no data rows")
    num = {}
    for c in (idcol, tcol, *pos):
        v = pd.to_numeric(df[c], errors="coerce")
        bad = v.isna() & df[c].notna()
        if bad.any():
            k = int(np.argmax(bad.to_numpy()))
            raise SandtrackError(f"{p}: column {c!r} row {k + 2}: {df[c].iloc[k]!r} is not a number")
        num[c] = v.to_numpy(float)
    ids = num[idcol]
    ok = np.isfinite(ids)
    if np.any(np.abs(ids[ok] - np.round(ids[ok])) > 1e-9) or (ok.any() and np.abs(ids[ok]).max() > 2 ** 62):
        raise SandtrackError(f"{p}: particle ids must be whole numbers")
    xyz = np.column_stack([num[c] for c in pos])[ok]
    more = {}
    for name in extra:
        if name in cols:
            more[name] = pd.to_numeric(df[cols[name]], errors="coerce").to_numpy(float)[ok]
    return to_rig(np.round(ids[ok]), num[tcol][ok], xyz, units or found_unit, axes, offset_mm,
                  time_offset_s, str(p), more)


def _open_text(p: Path) -> str:
    try:
        if p.suffix == ".gz":
            with gzip.open(p, "rt", encoding="utf-8", errors="replace") as fh:
                return fh.read()
        return p.read_text(encoding="utf-8", errors="replace")
    except (OSError, EOFError) as exc:
        raise SandtrackError(f"cannot read {p}: {exc}") from None


def _dump_paths(paths: str | Path | Sequence[str | Path]) -> list[Path]:
    if isinstance(paths, (str, Path)):
        paths = [paths]
    out: list[Path] = []
    for p in paths:
        s = str(p)
        if any(ch in s for ch in "*?["):
            hits = sorted(glob.glob(s), key=_natural_key)
            if not hits:
                raise SandtrackError(f"no file matches {s}")
            out.extend(Path(h) for h in hits)
        else:
            if not Path(s).is_file():
                raise SandtrackError(f"file not found: {s}")
            out.append(Path(s))
    return out


def _natural_key(s: str):
    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", s)]


def read_lammps_dump(paths, dt: float | None = None, units: str | None = None, axes: str = "x,y,z",
                     offset_mm: Sequence[float] = (0.0, 0.0, 0.0), time_offset_s: float = 0.0,
                     particle_ids: Sequence[int] | None = None, extra: Sequence[str] = ()) -> pd.DataFrame:
    """LIGGGHTS/LAMMPS ``dump custom`` file(s) -> the tidy DEM table (see module docstring).
    `extra`: ATOMS columns to keep as well when every step has them (e.g. "type", "radius")."""
    ids_all, t_all, xyz_all, more_all = [], [], [], []
    keep = None if particle_ids is None else np.asarray(sorted(set(int(i) for i in particle_ids)))
    for p in _dump_paths(paths):
        text = _open_text(p)
        if "ITEM: TIMESTEP" not in text:
            raise SandtrackError(f"{p}: not a LAMMPS/LIGGGHTS dump (no 'ITEM: TIMESTEP')")
        for block in text.split("ITEM: TIMESTEP")[1:]:
            ids, t, xyz, more = _parse_block(block, dt, p, extra)
            if keep is not None:
                m = np.isin(ids, keep)
                ids, xyz, more = ids[m], xyz[m], {k: v[m] for k, v in more.items()}
            ids_all.append(ids)
            t_all.append(np.full(len(ids), t))
            xyz_all.append(xyz)
            more_all.append(more)
    if not ids_all or sum(len(i) for i in ids_all) == 0:
        raise SandtrackError("the dump holds no (selected) particles")
    shared = [k for k in extra if all(k in m for m in more_all)]
    return to_rig(np.concatenate(ids_all), np.concatenate(t_all), np.concatenate(xyz_all), units, axes,
                  offset_mm, time_offset_s, str(paths if isinstance(paths, (str, Path)) else "dump"),
                  {k: np.concatenate([m[k] for m in more_all]) for k in shared})


def _parse_block(block: str, dt: float | None, p: Path, extra: Sequence[str] = ()):
    sections = re.split(r"^ITEM: ", block, flags=re.MULTILINE)
    try:
        step = int(sections[0].split()[0])
    except (IndexError, ValueError):
        raise SandtrackError(f"{p}: a TIMESTEP item without a step number") from None
    time_value = None
    bounds = None
    atoms_header, atoms_text = None, ""
    for sec in sections[1:]:
        head, _, body = sec.partition("\n")
        if head.startswith("TIME"):
            try:
                time_value = float(body.split()[0])
            except (IndexError, ValueError):
                raise SandtrackError(f"{p}: unreadable ITEM: TIME at step {step}") from None
        elif head.startswith("BOX BOUNDS"):
            try:
                rows = [list(map(float, ln.split()[:2])) for ln in body.strip().splitlines()[:3]]
                bounds = np.array(rows)
            except ValueError:
                raise SandtrackError(f"{p}: unreadable BOX BOUNDS at step {step}") from None
        elif head.startswith("ATOMS"):
            atoms_header = head.split()[1:]
            atoms_text = body
    if atoms_header is None:
        raise SandtrackError(f"{p}: step {step} has no ITEM: ATOMS section")
    if time_value is None:
        if dt is None:
            raise SandtrackError(f"{p}: no ITEM: TIME in the dump: give the DEM time step (--dt)")
        time_value = step * float(dt)
    if "id" not in atoms_header:
        raise SandtrackError(f"{p}: ATOMS columns lack 'id' ({' '.join(atoms_header)})")
    layouts = ((("x", "y", "z"), False), (("xu", "yu", "zu"), False), (("xs", "ys", "zs"), True),
               (("xsu", "ysu", "zsu"), True))
    found = next((lay for lay in layouts if all(n in atoms_header for n in lay[0])), None)
    if found is None:
        raise SandtrackError(f"{p}: ATOMS columns lack positions x y z ({' '.join(atoms_header)})")
    names, scaled = found
    if not atoms_text.strip():
        return np.zeros(0, np.int64), time_value, np.zeros((0, 3)), {k: np.zeros(0) for k in extra if k in atoms_header}
    try:
        arr = np.loadtxt(io.StringIO(atoms_text), ndmin=2)
    except ValueError as exc:
        raise SandtrackError(f"{p}: unreadable ATOMS rows at step {step} ({str(exc)[:80]})") from None
    if arr.shape[1] < len(atoms_header):
        raise SandtrackError(f"{p}: ATOMS rows at step {step} have fewer values than columns")
    col = {n: i for i, n in enumerate(atoms_header)}
    xyz = arr[:, [col[n] for n in names]]
    if scaled:
        if bounds is None or bounds.shape != (3, 2):
            raise SandtrackError(f"{p}: scaled positions need ITEM: BOX BOUNDS")
        xyz = bounds[:, 0] + xyz * (bounds[:, 1] - bounds[:, 0])
    more = {k: arr[:, col[k]] for k in extra if k in col}
    return arr[:, col["id"]].astype(np.int64), time_value, xyz, more


def read_dem(path, fmt: str | None = None, **kw) -> pd.DataFrame:
    """Read a DEM trajectory file: "csv" (exchange) or "dump" (LIGGGHTS/LAMMPS); default: by content."""
    if fmt is None:
        first = _dump_paths(path)[0] if not isinstance(path, (list, tuple)) else Path(path[0])
        try:
            with (gzip.open(first, "rt") if first.suffix == ".gz" else open(first, errors="replace")) as fh:
                head = fh.read(200)
        except OSError as exc:
            raise SandtrackError(f"cannot read {first}: {exc}") from None
        fmt = "dump" if "ITEM:" in head else "csv"
    if fmt == "dump":
        return read_lammps_dump(path, **kw)
    if fmt == "csv":
        kw.pop("dt", None)
        kw.pop("particle_ids", None)
        return read_exchange_csv(path, **kw)
    raise SandtrackError(f"unknown DEM format {fmt!r} (csv, dump)")


def write_exchange_csv(df: pd.DataFrame, path: str | Path, units: str = "m") -> None:
    """Write the tidy DEM table as the exchange CSV (x, y, z in `units`)."""
    s = 1.0 / UNIT_TO_MM[units]
    out = pd.DataFrame({"particle_id": df["particle_id"], "time_s": df["time_s"],
                        "x": df["X_mm"] * s, "y": df["Y_mm"] * s, "z": df["Z_mm"] * s})
    out.to_csv(path, index=False, float_format="%.9g")
