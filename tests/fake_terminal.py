"""A terminal screen rebuilt from the bytes a program writes: cursor moves, text, kitty graphics
(transmit, place, delete; PNG, RGB, RGBA, zlib) and sixel images, on a pixel canvas of
cols x rows cells of cell_w x cell_h pixels. Written from the protocols' specifications, not from
the code under test, so that decoding what sandtrack emits checks what a terminal would show.

Text written into a cell wipes the sixel pixels there (as xterm does) and leaves kitty images
alone (they sit in their own layer, here under the text: z < 0, and spaces have no glyph).
"""

from __future__ import annotations

import base64
import re
import zlib

import cv2
import numpy as np

UNSET = (255, 0, 255)  # canvas colour where nothing was drawn
TEXT = (0, 255, 0)  # pixels of a cell that text was written into (sixel layer)

_CSI = re.compile(r"\x1b\[([0-9;?<>=$ ]*)([@-~])")
_STRING = re.compile(r"\x1b([_P\]])(.*?)(?:\x1b\\|\x07)", re.S)
_SIXEL_TOKEN = re.compile(r'(#[\d;]+)|!(\d+)([?-~])|([?-~]+)|([$-])|"[\d;]*')


class FakeTerminal:
    def __init__(self, cols: int, rows: int, cell_px: tuple[int, int] = (10, 20)) -> None:
        self.cols, self.rows = cols, rows
        self.cw, self.ch = cell_px
        self.sixel = np.full((rows * self.ch, cols * self.cw, 3), UNSET, np.uint8)
        self.sixel_set = np.zeros(self.sixel.shape[:2], bool)
        self.images: dict[int, np.ndarray] = {}
        self.placements: dict[tuple[int, int], tuple[int, int, int, int]] = {}  # (id, p) -> col, row, c, r
        self.cursor = (0, 0)  # col, row
        self._saved = (0, 0)
        self._chunks: dict | None = None
        self._partial = ""
        self.text_cells = 0
        self.chars = [[" "] * cols for _ in range(rows)]
        self.kitty_commands: list[dict] = []
        self.sixel_images = 0

    # -- input ---------------------------------------------------------------------------------
    def feed(self, data: str | bytes) -> None:
        if isinstance(data, bytes):
            data = data.decode("utf-8", errors="replace")
        data = self._partial + data
        self._partial = ""
        i, n = 0, len(data)
        while i < n:
            c = data[i]
            if c == "\x1b":
                if i + 1 >= n:
                    self._partial = data[i:]
                    return
                nxt = data[i + 1]
                if nxt == "[":
                    m = _CSI.match(data, i)
                    if m is None:
                        self._partial = data[i:]
                        return
                    self._csi(m.group(1), m.group(2))
                    i = m.end()
                elif nxt in "_P]":
                    m = _STRING.match(data, i)
                    if m is None:
                        self._partial = data[i:]
                        return
                    if nxt == "_" and m.group(2).startswith("G"):
                        self._kitty(m.group(2)[1:])
                    elif nxt == "P":
                        self._dcs(m.group(2))
                    i = m.end()
                elif nxt == "7":
                    self._saved = self.cursor
                    i += 2
                elif nxt == "8":
                    self.cursor = self._saved
                    i += 2
                else:
                    i += 2
            elif c == "\r":
                self.cursor = (0, self.cursor[1])
                i += 1
            elif c == "\n":
                self.cursor = (self.cursor[0], min(self.cursor[1] + 1, self.rows - 1))
                i += 1
            elif c < " " or c == "\x7f":
                i += 1
            else:
                self._text(c)
                i += 1

    def _csi(self, params: str, final: str) -> None:
        if final in "Hf" and not params.startswith("?"):
            parts = [int(p) if p else 1 for p in params.split(";")] if params else [1, 1]
            row, col = (parts + [1, 1])[:2]
            self.cursor = (col - 1, row - 1)
        elif final == "C":
            self.cursor = (self.cursor[0] + (int(params) if params else 1), self.cursor[1])

    def _text(self, char: str) -> None:
        col, row = self.cursor
        if 0 <= col < self.cols and 0 <= row < self.rows:
            ys, xs = slice(row * self.ch, (row + 1) * self.ch), slice(col * self.cw, (col + 1) * self.cw)
            self.sixel[ys, xs] = TEXT
            self.sixel_set[ys, xs] = False
            self.text_cells += 1
            self.chars[row][col] = char
        self.cursor = (col + 1, row)

    # -- kitty ---------------------------------------------------------------------------------
    def _kitty(self, body: str) -> None:
        control, _, payload = body.partition(";")
        keys = dict(kv.split("=", 1) for kv in control.split(",") if "=" in kv)
        if self._chunks is not None:  # a continuation: only m (and q) are given
            self._chunks["payload"] += payload
            if keys.get("m", "0") == "0":
                cmd, self._chunks = self._chunks, None
                self._kitty_command(cmd["keys"], cmd["payload"])
            return
        if keys.get("m", "0") == "1":
            self._chunks = {"keys": keys, "payload": payload}
            return
        self._kitty_command(keys, payload)

    def _kitty_command(self, keys: dict, payload: str) -> None:
        self.kitty_commands.append(keys)
        action = keys.get("a", "t")
        iid = int(keys.get("i", 0))
        if action in "tT":
            data = base64.standard_b64decode(payload)
            if keys.get("o") == "z":
                data = zlib.decompress(data)
            fmt = int(keys.get("f", 32))
            if fmt == 100:
                img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)[:, :, ::-1]
            else:
                w, h, ch = int(keys["s"]), int(keys["v"]), 3 if fmt == 24 else 4
                img = np.frombuffer(data, np.uint8).reshape(h, w, ch)[:, :, :3]
            for k in [k for k in self.placements if k[0] == iid]:  # a new image under an id replaces the old
                del self.placements[k]
            self.images[iid] = np.ascontiguousarray(img)
            if action == "T":
                self._place(iid, keys)
        elif action == "p":
            self._place(iid, keys)
        elif action == "d":
            what = keys.get("d", "a")
            if what in "iI":
                pid = keys.get("p")
                for k in [k for k in self.placements if k[0] == iid and (pid is None or k[1] == int(pid))]:
                    del self.placements[k]
                if what == "I":
                    self.images.pop(iid, None)
            elif what in "aA":
                self.placements.clear()
                if what == "A":
                    self.images.clear()

    def _place(self, iid: int, keys: dict) -> None:
        img = self.images[iid]
        c = int(keys.get("c", 0)) or -(-img.shape[1] // self.cw)
        r = int(keys.get("r", 0)) or -(-img.shape[0] // self.ch)
        self.placements[(iid, int(keys.get("p", 0)))] = (*self.cursor, c, r)

    # -- sixel ---------------------------------------------------------------------------------
    def _dcs(self, body: str) -> None:
        m = re.match(r"([0-9;]*)q", body)
        if m is None:
            return
        self.sixel_images += 1
        params = [int(p) if p else 0 for p in m.group(1).split(";")] if m.group(1) else []
        if not (len(params) > 1 and params[1] == 1):
            raise AssertionError("only transparent-background sixel (P2=1) is expected")
        registers: dict[int, tuple[int, int, int]] = {}
        colours: list[tuple[int, int, int]] = []
        colour = -1
        x = band = 0
        seg_x, seg_band, seg_colour, seg_len, chunks = [], [], [], [], []
        for tok in _SIXEL_TOKEN.finditer(body, m.end()):
            define, count, char, chars, control = tok.groups()
            if define is not None:
                parts = [int(p) for p in define[1:].split(";")]
                if len(parts) == 5:
                    assert parts[1] == 2, "only RGB colour definitions are expected"
                    registers[parts[0]] = tuple(round(v * 255 / 100) for v in parts[2:])
                colours.append(registers[parts[0]])
                colour = len(colours) - 1
            elif count is not None or chars is not None:
                data = char * int(count) if count is not None else chars
                seg_x.append(x)
                seg_band.append(band)
                seg_colour.append(colour)
                seg_len.append(len(data))
                chunks.append(data)
                x += len(data)
            elif control is not None:
                band += control == "-"
                x = 0
        if not chunks:
            return
        # every sixel column as (x, band, colour, 6 bits), in drawing order; a later one paints over
        lens = np.array(seg_len)
        seg = np.repeat(np.arange(len(lens)), lens)
        starts = np.cumsum(lens) - lens
        xs = np.array(seg_x)[seg] + np.arange(len(seg)) - starts[seg]
        vals = np.frombuffer("".join(chunks).encode(), np.uint8).astype(np.int64) - 63
        h, w = self.sixel.shape[:2]
        x0, y0 = self.cursor[0] * self.cw, self.cursor[1] * self.ch
        bands, seg_colour = np.array(seg_band), np.array(seg_colour)
        hits = [(vals >> r & 1).astype(bool) for r in range(6)]
        ys = np.concatenate([y0 + 6 * bands[seg[hit]] + r for r, hit in enumerate(hits)])
        xs = np.concatenate([x0 + xs[hit] for hit in hits])
        segs = np.concatenate([seg[hit] for hit in hits])
        order = np.argsort(segs, kind="stable")  # drawing order
        ys, xs, cid = ys[order], xs[order], seg_colour[segs[order]]
        inside = (ys >= 0) & (ys < h) & (xs >= 0) & (xs < w)
        ys, xs, cid = ys[inside], xs[inside], cid[inside]
        flat = ys * w + xs
        _, last = np.unique(flat[::-1], return_index=True)  # the last writer of each pixel
        pick = len(flat) - 1 - last
        self.sixel[ys[pick], xs[pick]] = np.array(colours, np.uint8)[cid[pick]]
        self.sixel_set[ys[pick], xs[pick]] = True

    # -- output --------------------------------------------------------------------------------
    def screen(self) -> np.ndarray:
        """The pixels on screen: sixel pixels, with kitty placements drawn under text (in order)."""
        out = self.sixel.copy()
        for (iid, _), (col, row, c, r) in self.placements.items():
            img = self.images[iid]
            w, h = c * self.cw, r * self.ch
            if img.shape[:2] != (h, w):
                img = cv2.resize(img, (w, h), interpolation=cv2.INTER_NEAREST)
            y, x = row * self.ch, col * self.cw
            hh, ww = min(h, out.shape[0] - y), min(w, out.shape[1] - x)
            out[y:y + hh, x:x + ww] = img[:hh, :ww]
        return out

    def graphics_mask(self) -> np.ndarray:
        """Pixels covered by a picture (sixel pixels not wiped by text, kitty placements)."""
        mask = self.sixel_set.copy()
        for col, row, c, r in self.placements.values():
            mask[row * self.ch:(row + r) * self.ch, col * self.cw:(col + c) * self.cw] = True
        return mask

    def line(self, row: int) -> str:
        return "".join(self.chars[row])

    def region(self, col: int, row: int, cols: int, rows: int) -> np.ndarray:
        return self.screen()[row * self.ch:(row + rows) * self.ch, col * self.cw:(col + cols) * self.cw]


# --------------------------------------------------------------------------------------------
# a program on a real pseudo-terminal, with a terminal that answers its questions
# --------------------------------------------------------------------------------------------
KITTY_QUERY = re.compile(rb"\x1b_Gi=(\d+)[^;]*a=q[^;]*;[^\x1b]*\x1b\\")
SIXEL_END = "\x1b8\x1b[?2026l"  # how sandtrack ends each graphics write (Textual never writes ESC 8)


def answer(data: bytes, kitty: bool, sixel: bool, cell_px=(10, 20)) -> tuple[bytes, bytes]:
    """What a terminal offering `kitty` and/or `sixel` graphics replies to the queries in `data`,
    in order, and the rest of `data` after the last query answered."""
    cw, ch = cell_px
    questions = [
        (KITTY_QUERY, (lambda q: b"\x1b_Gi=" + KITTY_QUERY.match(q).group(1) + b";OK\x1b\\") if kitty else b""),
        (re.compile(rb"\x1b\[16t"), f"\x1b[6;{ch};{cw}t".encode()),
        (re.compile(rb"\x1b\[14t"), b""),
        (re.compile(rb"\x1b\[\?1;1;0S"), b"\x1b[?1;0;256S" if sixel else b""),
        (re.compile(rb"\x1b\[0?c"), b"\x1b[?62;4;22c" if sixel else b"\x1b[?62;22c"),
        (re.compile(rb"\x1b\[\?2026\$p"), b"\x1b[?2026;2$y"),
    ]
    replies = []
    while True:
        hits = [(m.start(), m.end(), r) for pat, r in questions for m in [pat.search(data)] if m]
        if not hits:
            return b"".join(replies), data
        start, end, reply = min(hits, key=lambda h: h[0])
        replies.append(reply(data[start:end]) if callable(reply) else reply)
        data = data[end:]


class PtyTerminal:
    """Runs `argv` on a pty of cols x rows cells (cell_px pixels each) as its controlling terminal
    and answers what a terminal offering `kitty` and/or `sixel` graphics would: the kitty graphics
    query, cell and text area size, colour registers, DA1, and Textual's mode queries. Every chunk
    of output is kept with its arrival time (time.perf_counter)."""

    def __init__(self, argv: list[str], cols: int = 200, rows: int = 50, cell_px=(10, 20), kitty: bool = False,
                 sixel: bool = False, env: dict | None = None, cwd=None) -> None:
        import fcntl
        import os
        import struct
        import subprocess
        import termios
        import threading

        self.kitty, self.sixel, self.cell_px = kitty, sixel, cell_px
        # the size comes from the pty, as in a real terminal: COLUMNS/LINES (set by pytest-xdist) would override it
        env = {k: v for k, v in (os.environ if env is None else env).items() if k not in ("COLUMNS", "LINES")}
        self.master, slave = os.openpty()
        fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", rows, cols, cols * cell_px[0], rows * cell_px[1]))

        def controlling_tty():
            fcntl.ioctl(0, termios.TIOCSCTTY, 0)

        self.proc = subprocess.Popen(argv, stdin=slave, stdout=slave, stderr=slave, start_new_session=True,
                                     preexec_fn=controlling_tty, env=env, cwd=cwd, close_fds=True)
        os.close(slave)
        self.chunks: list[tuple[float, bytes]] = []
        self._lock = threading.Lock()
        self._scan = b""
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        import os
        import time

        while True:
            try:
                data = os.read(self.master, 1 << 16)
            except OSError:
                return
            if not data:
                return
            with self._lock:
                self.chunks.append((time.perf_counter(), data))
            self._answer(data)

    def _answer(self, data: bytes) -> None:
        import os

        self._scan = (self._scan + data)[-4096:]
        replies, self._scan = answer(self._scan, self.kitty, self.sixel, self.cell_px)
        if replies:
            os.write(self.master, replies)

    def write(self, data: bytes) -> float:
        import os
        import time

        t = time.perf_counter()
        os.write(self.master, data)
        return t

    def since(self, t: float) -> list[tuple[float, bytes]]:
        with self._lock:
            return [c for c in self.chunks if c[0] >= t]

    def wait_quiet(self, quiet: float = 0.3, timeout: float = 30.0) -> None:
        """Until nothing arrived for `quiet` seconds (counted from the call at the earliest)."""
        import time

        t0 = time.perf_counter()
        while time.perf_counter() - t0 < timeout:
            with self._lock:
                last = max(self.chunks[-1][0], t0) if self.chunks else None
            if last is not None and time.perf_counter() - last >= quiet:
                return
            if self.proc.poll() is not None:
                raise RuntimeError(f"the program ended (exit status {self.proc.returncode})")
            time.sleep(0.005)
        raise TimeoutError("the program kept writing")

    def cpu_ms(self) -> tuple[float, float]:
        """CPU time the program has used so far (ms): all its threads, and its main (UI) thread alone
        (Linux /proc/PID/task/*/schedstat, nanoseconds)."""
        import glob

        total = main = 0.0
        for path in glob.glob(f"/proc/{self.proc.pid}/task/*/schedstat"):
            try:
                with open(path) as f:
                    ns = int(f.read().split()[0])
            except (OSError, ValueError, IndexError):
                continue  # a thread that just ended
            total += ns
            if path.split("/")[-2] == str(self.proc.pid):
                main = ns
        return total / 1e6, main / 1e6

    def output(self) -> bytes:
        with self._lock:
            return b"".join(c[1] for c in self.chunks)

    def close(self, keys: bytes = b"q", timeout: float = 20.0) -> int:
        import os
        import subprocess

        if self.proc.poll() is None:
            self.write(keys)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self._reader.join(timeout=2)
        os.close(self.master)
        return self.proc.returncode
