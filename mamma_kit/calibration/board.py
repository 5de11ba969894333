"""ChArUco board specs (TOML in calib/), the OpenCV board they describe, and printing.

A spec file::

    name = "charuco-a1"
    squares_x = 5            # squares along the board's x (columns of the printed image)
    squares_y = 7            # squares along y (rows)
    square_m = 0.110         # side of a chessboard square (m) - measure your print!
    marker_m = 0.085         # side of an ArUco marker (m)
    dictionary = "DICT_4X4_50"
    legacy = false           # boards printed by OpenCV < 4.6 (matters only for an even squares_y)
    inverted = false         # white markers on black (inverted colours)
    paper = "A1"             # default paper for `mamma-kit board`

Caliscope's charuco.toml (columns, rows, square_size_override_cm, aruco_scale, dictionary,
inverted) is read as well.

Board coordinates follow OpenCV: origin at the top-left corner of the printed pattern,
x along the columns, y down the rows, z into the board (a camera looking at the printed
face sees z pointing away from it). Chessboard corner j sits at
((j % (squares_x-1) + 1) * square_m, (j // (squares_x-1) + 1) * square_m, 0).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace
from pathlib import Path

import cv2
import numpy as np

from mamma_kit.core.errors import UserError
from mamma_kit.core.io import read_toml

# paper sizes in mm (portrait: width, height)
PAPERS = {"A0": (841, 1189), "A1": (594, 841), "A2": (420, 594), "A3": (297, 420), "A4": (210, 297),
          "letter": (215.9, 279.4), "tabloid": (279.4, 431.8)}

DICTIONARIES = {n[5:]: getattr(cv2.aruco, n) for n in dir(cv2.aruco)
                if n.startswith("DICT_") and n[5:].upper() == n[5:]}


def dictionary_id(name: str) -> int:
    key = str(name).upper().removeprefix("DICT_")
    if key not in DICTIONARIES:
        raise UserError(f"unknown ArUco dictionary '{name}'",
                        f"use one of {', '.join('DICT_' + k for k in sorted(DICTIONARIES))}")
    return DICTIONARIES[key]


def dictionary_name(name: str) -> str:
    dictionary_id(name)
    return "DICT_" + str(name).upper().removeprefix("DICT_")


@dataclass(frozen=True)
class BoardSpec:
    squares_x: int
    squares_y: int
    square_m: float
    marker_m: float
    dictionary: str = "DICT_4X4_50"
    legacy: bool = False
    inverted: bool = False
    name: str = "board"
    paper: str | None = None

    def __post_init__(self):
        if self.squares_x < 2 or self.squares_y < 2:
            raise UserError(f"board {self.name}: needs at least 2x2 squares (got {self.squares_x}x{self.squares_y})",
                            "set squares_x and squares_y to the counts on the print")
        if not 0 < self.marker_m < self.square_m:
            raise UserError(f"board {self.name}: marker_m ({self.marker_m}) must be positive and smaller than "
                            f"square_m ({self.square_m})", "measure the printed square and marker sides in metres")
        if self.square_m > 1.0:
            raise UserError(f"board {self.name}: square_m = {self.square_m} m is implausible",
                            "give sizes in metres (0.04 for 4 cm)")
        object.__setattr__(self, "dictionary", dictionary_name(self.dictionary))
        d = cv2.aruco.getPredefinedDictionary(dictionary_id(self.dictionary))
        n_markers = (self.squares_x * self.squares_y) // 2
        if n_markers > d.bytesList.shape[0]:
            raise UserError(f"board {self.name}: {n_markers} markers do not fit {self.dictionary} "
                            f"({d.bytesList.shape[0]} markers)", "choose a larger dictionary or fewer squares")

    # ---- derived ------------------------------------------------------------------------
    @property
    def n_corners(self) -> int:
        return (self.squares_x - 1) * (self.squares_y - 1)

    @property
    def size_m(self) -> tuple[float, float]:
        """Pattern width, height (m)."""
        return self.squares_x * self.square_m, self.squares_y * self.square_m

    @property
    def corners_b3(self) -> np.ndarray:
        """Chessboard corners in board coordinates (n_corners, 3), in OpenCV id order."""
        n = self.squares_x - 1
        j = np.arange(self.n_corners)
        return np.stack([(j % n + 1) * self.square_m, (j // n + 1) * self.square_m, np.zeros(len(j))], -1)

    @property
    def center_b3(self) -> np.ndarray:
        w, h = self.size_m
        return np.array([w / 2, h / 2, 0.0])

    def cv_board(self) -> "cv2.aruco.CharucoBoard":
        b = cv2.aruco.CharucoBoard((self.squares_x, self.squares_y), self.square_m, self.marker_m,
                                   cv2.aruco.getPredefinedDictionary(dictionary_id(self.dictionary)))
        b.setLegacyPattern(bool(self.legacy))
        return b

    def detector(self, *, inverted: bool | None = None, refine: bool = True) -> "cv2.aruco.CharucoDetector":
        """A CharucoDetector for this board (subpixel marker corners, inverted if the spec says so)."""
        dp = cv2.aruco.DetectorParameters()
        dp.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
        dp.detectInvertedMarker = bool(self.inverted if inverted is None else inverted)
        cp = cv2.aruco.CharucoParameters()
        cp.tryRefineMarkers = bool(refine)
        cp.minMarkers = 1
        return cv2.aruco.CharucoDetector(self.cv_board(), cp, dp)

    def image(self, px_per_square: int, margin_px: int = 0) -> np.ndarray:
        """The printed pattern as a uint8 image; pixel (i, j)'s centre is board point
        ((j + 0.5 - margin_px) / px_per_square * square_m, (i + 0.5 - margin_px) / ...)."""
        p = int(px_per_square)
        img = self.cv_board().generateImage((self.squares_x * p, self.squares_y * p), marginSize=0, borderBits=1)
        if self.inverted:
            img = 255 - img
        if margin_px:
            img = cv2.copyMakeBorder(img, margin_px, margin_px, margin_px, margin_px, cv2.BORDER_CONSTANT, value=255)
        return img

    def to_dict(self) -> dict:
        d = asdict(self)
        if d["paper"] is None:
            d.pop("paper")
        return d

    def describe(self) -> str:
        extra = [s for s, on in (("legacy layout", self.legacy), ("inverted", self.inverted)) if on]
        return (f"{self.name}: {self.squares_x}x{self.squares_y} squares of {self.square_m * 1000:g} mm, markers "
                f"{self.marker_m * 1000:g} mm, {self.dictionary}" + (f", {', '.join(extra)}" if extra else ""))

    def with_(self, **changes) -> "BoardSpec":
        return replace(self, **changes)


FIELDS = {"squares_x": int, "squares_y": int, "square_m": float, "marker_m": float, "dictionary": str,
          "legacy": bool, "inverted": bool, "name": str, "paper": str}


def spec_from_dict(d: dict, name: str = "board", where: str = "board spec") -> BoardSpec:
    d = dict(d.get("board", d)) if isinstance(d.get("board"), dict) else dict(d)
    unknown = sorted(set(d) - set(FIELDS) - {"format", "version", "notes"})
    if unknown:
        raise UserError(f"{where}: unknown field(s) {', '.join(unknown)}", f"use only {', '.join(FIELDS)}")
    missing = [k for k in ("squares_x", "squares_y", "square_m", "marker_m") if k not in d]
    if missing:
        raise UserError(f"{where} is missing {', '.join(missing)}",
                        "give squares_x, squares_y, square_m, marker_m (metres) and dictionary")
    kw = {}
    for k, typ in FIELDS.items():
        if k in d:
            v = d[k]
            if typ is bool and not isinstance(v, bool):
                raise UserError(f"{where}: '{k}' must be true or false", f"write {k} = false")
            if typ in (int, float) and (isinstance(v, bool) or not isinstance(v, (int, float))):
                raise UserError(f"{where}: '{k}' must be a number", f"write e.g. {k} = 5")
            if typ is int and int(v) != v:
                raise UserError(f"{where}: '{k}' must be a whole number", f"write e.g. {k} = 5")
            kw[k] = typ(v)
    kw.setdefault("name", name)
    if kw.get("paper") is not None and kw["paper"] not in PAPERS:
        raise UserError(f"{where}: unknown paper '{kw['paper']}'", f"use one of {', '.join(PAPERS)}")
    return BoardSpec(**kw)


CALISCOPE_UNITS_M = {"inch": 0.0254, "cm": 0.01, "mm": 0.001, "m": 1.0}


def spec_from_caliscope(d: dict, name: str = "board", where: str = "charuco.toml") -> BoardSpec:
    """A Caliscope charuco.toml: columns, rows, board_width/board_height (paper, in ``units``),
    square_size_override_cm (the measured square), aruco_scale (marker side / square side),
    dictionary, inverted. Without the override the square is the paper divided by the squares."""
    try:
        cols, rows = int(d["columns"]), int(d["rows"])
        if d.get("square_size_override_cm") not in (None, "", 0):
            square = float(d["square_size_override_cm"]) / 100.0
        else:
            unit = CALISCOPE_UNITS_M.get(str(d.get("units", "inch")).lower())
            if unit is None:
                raise UserError(f"{where}: unknown units '{d.get('units')}'", "use inch or cm")
            square = min(float(d["board_width"]) / cols, float(d["board_height"]) / rows) * unit
        marker = float(d.get("aruco_scale", 0.75)) * square
    except (KeyError, TypeError, ValueError) as e:
        raise UserError(f"{where}: not a complete Caliscope board ({e})",
                        "give columns, rows, square_size_override_cm and aruco_scale") from None
    square, marker = round(square, 9), round(marker, 9)  # 5.4 cm -> 0.054 m, not 0.054000000000000006
    return BoardSpec(cols, rows, square, marker, str(d.get("dictionary", "DICT_4X4_50")), inverted=bool(
        d.get("inverted", False)), name=name)


def builtin_specs_dir() -> Path:
    """calib/ of the source tree (specs ship with the repo)."""
    return Path(__file__).resolve().parents[2] / "calib"


def load_board_spec(path_or_name: str | Path) -> BoardSpec:
    """Read a spec TOML; a bare name (e.g. ``charuco-a1``) is looked up in calib/."""
    p = Path(path_or_name)
    if not p.exists() and p.suffix == "" and (builtin_specs_dir() / f"{p.name}.toml").is_file():
        p = builtin_specs_dir() / f"{p.name}.toml"
    if not p.is_file():
        avail = sorted(q.stem for q in builtin_specs_dir().glob("charuco*.toml"))
        raise UserError(f"board spec not found: {path_or_name}",
                        f"pass a spec TOML (built in: {', '.join(avail) or 'none'})")
    data = read_toml(p, "board spec")
    if "columns" in data and "rows" in data and "squares_x" not in data:
        return spec_from_caliscope(data, name=p.stem, where=f"board spec {p.name}")
    return spec_from_dict(data, name=p.stem, where=f"board spec {p.name}")


# ---- printing ---------------------------------------------------------------------------
def _board_rects(spec: BoardSpec) -> list[tuple[float, float, float, float]]:
    """Black rectangles (x, y, w, h) in board metres that make up the printed pattern
    (before colour inversion), exactly as OpenCV draws it: chessboard squares plus marker
    bits. Derived from OpenCV's own board so legacy layouts and ids match."""
    board = spec.cv_board()
    s = spec.square_m
    # which squares are black: sample a low-res rendering near each square's corner, where
    # markers never reach
    p = 40
    img = board.generateImage((spec.squares_x * p, spec.squares_y * p), marginSize=0, borderBits=1)
    rects = []
    for r in range(spec.squares_y):
        for c in range(spec.squares_x):
            if img[r * p + 2, c * p + 2] < 128:
                rects.append((c * s, r * s, s, s))
    d = board.getDictionary()
    bits = d.markerSize
    cell = spec.marker_m / (bits + 2)
    for mid, obj in zip(board.getIds().ravel(), board.getObjPoints()):
        x0, y0 = np.asarray(obj)[0, :2]
        m = cv2.aruco.generateImageMarker(d, int(mid), bits + 2, borderBits=1)
        ys, xs = np.nonzero(m < 128)
        rects += [(x0 + cx * cell, y0 + cy * cell, cell, cell) for cy, cx in zip(ys, xs)]
    return rects


def choose_paper(spec: BoardSpec, paper: str | None, margin_mm: float = 10.0, text_mm: float = 22.0) -> tuple[str, bool]:
    """-> (paper, landscape). Picks the smallest paper the pattern fits when none is given."""
    w_mm, h_mm = (v * 1000 for v in spec.size_m)

    def fits(name):
        pw, ph = PAPERS[name]
        for land in (False, True):
            W, H = (ph, pw) if land else (pw, ph)
            if w_mm + 2 * margin_mm <= W and h_mm + 2 * margin_mm + text_mm <= H:
                return land
        return None

    if paper is None:
        paper = spec.paper
    if paper is not None:
        if paper not in PAPERS:
            raise UserError(f"unknown paper '{paper}'", f"use one of {', '.join(PAPERS)}")
        land = fits(paper)
        if land is None:
            bigger = [n for n in ("A4", "letter", "A3", "A2", "A1", "A0") if fits(n) is not None]
            raise UserError(f"board {spec.name} ({w_mm:.0f} x {h_mm:.0f} mm) does not fit on {paper} with margins",
                            f"use --paper {bigger[0]}" if bigger else "use a smaller square_m in the spec")
        return paper, land
    for n in ("A4", "letter", "A3", "A2", "A1", "A0"):
        land = fits(n)
        if land is not None:
            return n, land
    raise UserError(f"board {spec.name} ({w_mm:.0f} x {h_mm:.0f} mm) is larger than A0",
                    "use smaller squares (square_m) or fewer squares")


def _draw_page(spec: BoardSpec, paper: str, W: float, H: float, *, back: bool, double_sided: bool,
               text_mm: float):
    """One page (a matplotlib Figure, mm with y down): the pattern, or its mirror image for
    the back of a double-sided board, with the spec, notes, a 100 mm bar and, on double-sided
    boards, corner marks to align the two pages. -> (figure, pattern's top-left in mm)."""
    from matplotlib.collections import PatchCollection
    from matplotlib.figure import Figure
    from matplotlib.patches import Rectangle

    w_mm, h_mm = (v * 1000 for v in spec.size_m)
    fig = Figure(figsize=(W / 25.4, H / 25.4))
    ax = fig.add_axes((0, 0, 1, 1))
    ax.set_xlim(0, W)
    ax.set_ylim(H, 0)  # y down, mm from the page's top-left
    ax.set_axis_off()
    # centred horizontally, so the mirrored pattern lands on the same part of the page; room
    # for the text block below the pattern
    x0 = (W - w_mm) / 2
    y0 = 10.0 + max(0.0, (H - 20.0 - text_mm - h_mm) / 2)
    fg, bg = ("white", "black") if spec.inverted else ("black", "white")
    if spec.inverted:
        ax.add_patch(Rectangle((x0, y0), w_mm, h_mm, facecolor="black", edgecolor="none"))
    rects = _board_rects(spec)
    if back:  # mirror image about the pattern's vertical centre line (= the page's)
        rects = [(spec.size_m[0] - x - w, y, w, h) for x, y, w, h in rects]
    rects = [Rectangle((x0 + x * 1000, y0 + y * 1000), w * 1000, h * 1000) for x, y, w, h in rects]
    # tiny overlap-free rectangles; antialiasing off so neighbours do not leave hairlines
    ax.add_collection(PatchCollection(rects, facecolor=fg, edgecolor="none", antialiased=False))
    if double_sided:
        # crosses 4 mm left and right of the pattern's corners (a set the mirror maps onto
        # itself), beside it so that no paper gets taller
        for cx in (x0 - 4, x0 + w_mm + 4):
            for cy in (y0, y0 + h_mm):
                ax.add_patch(Rectangle((cx - 3, cy - 0.15), 6, 0.3, facecolor="black", edgecolor="none"))
                ax.add_patch(Rectangle((cx - 0.15, cy - 3), 0.3, 6, facecolor="black", edgecolor="none"))
    ty = y0 + h_mm + 4
    lines = [
        f"mamma-kit ChArUco board '{spec.name}': {spec.squares_x} x {spec.squares_y} squares, "
        f"square {spec.square_m * 1000:g} mm, marker {spec.marker_m * 1000:g} mm, {spec.dictionary}, "
        f"legacy={'true' if spec.legacy else 'false'}, inverted={'true' if spec.inverted else 'false'}",
        f"Print at 100 % (actual size) on {paper}. The bar below must measure 100 mm and a square "
        f"{spec.square_m * 1000:g} mm; if not, write the measured sizes into the spec.",
    ]
    fs = 7 if W < 300 else 9
    if double_sided:
        import textwrap

        # DejaVu Sans averages about 0.55 em a character; 1 pt = 0.3528 mm
        width = max(40, int((W - x0 - 8) / (0.55 * fs * 0.3528)))
        note = ("turn page 2 over left to right (like a book page), hold it behind page 1 against a window, lay "
                "the crosses and squares on each other and glue the sheets to each other (nothing thick between: "
                "any offset is an error for cameras behind).")
        side = "Page 2 of 2: the BACK (mirror image); " if back else "Page 1 of 2: the FRONT; "
        lines += textwrap.wrap(side + note, width)
    for k, text in enumerate(lines):
        ax.text(x0, ty + k * 4.0, text, fontsize=fs, va="top", ha="left", family="DejaVu Sans")
    bar_y = ty + len(lines) * 4.0 + 3
    ax.add_patch(Rectangle((x0, bar_y), 100.0, 2.0, facecolor="black", edgecolor="none"))
    for k in range(11):
        ax.add_patch(Rectangle((x0 + 10 * k - 0.15, bar_y - (2 if k % 5 == 0 else 1)), 0.3,
                               2 if k % 5 == 0 else 1, facecolor="black", edgecolor="none"))
    ax.text(x0 + 102, bar_y + 1, "100 mm", fontsize=fs, va="center")
    return fig, (x0, y0)


def back_page_path(out: str | Path) -> Path:
    """Where the back page of a double-sided board goes when the format holds one page."""
    out = Path(out)
    return out.with_name(f"{out.stem}-back{out.suffix}")


def print_board(spec: BoardSpec, out: str | Path, paper: str | None = None, dpi: int = 300,
                double_sided: bool = False) -> dict:
    """Write the board at true physical scale on a page (PDF vector or PNG at ``dpi``),
    with the spec and a 100 mm check bar in the margin. Returns what was written.

    ``double_sided`` adds the back: the pattern's mirror image on a second page (of the PDF;
    ``<stem>-back.png|svg`` beside a PNG or SVG) to glue back to back with the first, so
    that a camera behind the board sees every corner at the same point as the front's."""
    import matplotlib

    matplotlib.use("Agg")

    from mamma_kit.core.io import atomic_path

    out = Path(out)
    ext = out.suffix.lower()
    if ext not in (".pdf", ".png", ".svg"):
        raise UserError(f"cannot write a board as '{ext or out.name}'", "use --out board.pdf, board.png or board.svg")
    text_mm = 25.0 if double_sided else 22.0
    paper, land = choose_paper(spec, paper, text_mm=text_mm)
    pw, ph = PAPERS[paper]
    W, H = (ph, pw) if land else (pw, ph)  # page in mm
    w_mm, h_mm = (v * 1000 for v in spec.size_m)
    sides = [False, True] if double_sided else [False]
    figs = [_draw_page(spec, paper, W, H, back=b, double_sided=double_sided, text_mm=text_mm) for b in sides]
    x0, y0 = figs[0][1]
    pages = [str(out)]
    if ext == ".pdf" and double_sided:
        from matplotlib.backends.backend_pdf import PdfPages

        with atomic_path(out) as tmp:
            with PdfPages(tmp) as pdf:
                for fig, _ in figs:
                    pdf.savefig(fig, facecolor="white")
    else:
        with atomic_path(out) as tmp:
            figs[0][0].savefig(tmp, dpi=dpi, format=ext[1:], facecolor="white")
        if double_sided:
            back = back_page_path(out)
            with atomic_path(back) as tmp:
                figs[1][0].savefig(tmp, dpi=dpi, format=ext[1:], facecolor="white")
            pages.append(str(back))
    return {"output": str(out), "paper": paper, "landscape": land, "page_mm": [W, H],
            "board_mm": [w_mm, h_mm], "board_origin_mm": [x0, y0], "dpi": dpi if ext == ".png" else None,
            "double_sided": double_sided, "pages": len(sides), "files": pages,
            "spec": spec.to_dict()}
