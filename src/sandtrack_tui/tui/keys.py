"""Key bindings of the main view: one table drives the bindings, the footer, the `?` help screen
and the command palette."""

from __future__ import annotations

from textual.binding import Binding

# (key, action, description, group, shown in footer)
KEYS = [
    ("right,full_stop", "step(1)", "next frame", "Navigate", True),
    ("left,comma", "step(-1)", "previous frame", "Navigate", False),
    ("shift+right", "step(10)", "+10 frames", "Navigate", False),
    ("shift+left", "step(-10)", "-10 frames", "Navigate", False),
    ("pagedown", "step(50)", "+50 frames", "Navigate", False),
    ("pageup", "step(-50)", "-50 frames", "Navigate", False),
    ("home", "go(0)", "first frame", "Navigate", False),
    ("end", "go(-1)", "last frame", "Navigate", False),
    ("g", "goto", "go to frame…", "Navigate", False),
    ("space", "play", "play / pause", "Navigate", True),
    ("n", "problem(1)", "next problem (lost, occluded, gap)", "Navigate", True),
    ("N", "problem(-1)", "previous problem", "Navigate", False),
    ("1,2,3,4,5,6,7,8", "", "select marker 1-8 (a new number starts a new marker)", "Markers", False),
    ("tab", "switch_view", "switch the active view (next camera)", "Markers", False),
    ("m", "marker_list", "marker list: nearest the cursor first; select, rename (r), merge (M)", "Markers", False),
    ("M", "merge", "merge the selected marker into another (two ids on one bead)", "Markers", False),
    ("h,j,k,l", "", "move the cursor (H J K L: 8x)", "Seed", False),
    ("enter", "seed_cursor", "place the selected marker at the cursor", "Seed", True),
    ("A", "auto_seed", "auto-seed: the markers like the seeded one, or every particle", "Seed", False),
    ("t", "track(1,0)", "track the selected marker forward", "Track", True),
    ("T", "track(-1,0)", "track the selected marker backward", "Track", False),
    ("r", "track(1,1)", "track all markers forward", "Track", False),
    ("R", "track(-1,1)", "track all markers backward", "Track", False),
    ("escape", "cancel", "cancel the running task", "Track", False),
    ("w,a,s,d", "", "nudge the selected point 1 px (W A S D: 5 px)", "Correct", False),
    ("c", "scale", "one camera: px -> mm scale, press at both ends of a known length", "Correct", False),
    ("o", "occlude", "mark occluded (range if set, else this frame)", "Correct", False),
    ("left_square_bracket", "mark_in", "range start [", "Correct", False),
    ("right_square_bracket", "mark_out", "range end ]", "Correct", False),
    ("delete,backspace", "delete", "delete points (range if set, else this frame)", "Correct", False),
    ("i", "interpolate", "interpolate the gap (range if set, else the gap here)", "Correct", False),
    ("X", "swap", "swap identities with another marker over the range", "Correct", False),
    ("u,ctrl+z", "undo", "undo", "Correct", True),
    ("U,ctrl+y", "redo", "redo", "Correct", False),
    ("z", "zoom_marker", "zoom to the selected marker and follow it", "View", False),
    ("plus,equals_sign", "zoom(2)", "zoom in", "View", False),
    ("minus", "zoom(0.5)", "zoom out", "View", False),
    ("0", "zoom_fit", "fit the whole frame", "View", False),
    ("b", "toggle_boost", "marker boost on / off", "View", False),
    ("v", "cycle_layout", "layout: views + timeline + table / no table / views only", "View", False),
    ("f2", "screen('sync')", "sync", "Screens", False),
    ("f3", "screen('calibration')", "calibration", "Screens", False),
    ("f4", "screen('training')", "train the regression model", "Screens", False),
    ("e,f5", "screen('export')", "export trajectories", "Screens", True),
    ("f6", "screen('compare')", "DEM comparison", "Screens", False),
    ("f7", "screen('repose')", "angle of repose and DEM parameter sweep", "Screens", False),
    ("question_mark", "help", "help", "Screens", True),
    ("q", "quit", "quit", "Screens", True),
]

KEY_DISPLAY = {"left_square_bracket": "[", "right_square_bracket": "]", "question_mark": "?",
               "full_stop": ".", "comma": ",", "plus": "+", "equals_sign": "=", "minus": "-"}


FOOTER = {"step(1)": "next", "play": "play", "problem(1)": "problem", "seed_cursor": "place", "track(1,0)": "track",
          "marker_list": "markers", "undo": "undo", "zoom_marker": "zoom", "screen('export')": "export",
          "help": "help", "quit": "quit"}


def bindings() -> list[Binding]:
    out = []
    for keys, action, desc, _group, show in KEYS:
        if not action:
            continue
        first = keys.split(",")[0]
        out.append(Binding(keys, action, FOOTER.get(action, desc.split(" (")[0]), show=show,
                           key_display=KEY_DISPLAY.get(first), priority=keys == "tab"))
    for n in range(1, 9):
        out.append(Binding(str(n), f"select({n})", f"marker {n}", show=False))
    for k, (dx, dy) in {"h": (-1, 0), "j": (0, 1), "k": (0, -1), "l": (1, 0)}.items():
        out.append(Binding(k, f"cursor({dx},{dy},1)", "cursor", show=False))
        out.append(Binding(k.upper(), f"cursor({dx},{dy},8)", "cursor fast", show=False))
    for k, (dx, dy) in {"a": (-1, 0), "s": (0, 1), "w": (0, -1), "d": (1, 0)}.items():
        out.append(Binding(k, f"nudge({dx},{dy})", "nudge", show=False))
        out.append(Binding(k.upper(), f"nudge({5 * dx},{5 * dy})", "nudge 5 px", show=False))
    return out


# Actions that act on the main screen's views: off while another screen (sync, export, ...) is shown.
ANYWHERE = {"quit", "help", "cancel", "command_palette"}
