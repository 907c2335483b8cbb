"""The interactive deviation map of one inspection (``--html``): one self-contained HTML file.

The page shows what the PDF's deviation map shows, in 3-D: the registered nominal coloured
by its signed deviation with the PDF's colours (:func:`~qifreport.reports.render.deviation_colors`
under the same per-vertex bands and colour scale: green in the band, red proud, blue sunk,
grey unscored), the out-of-tolerance regions outlined (the band edge,
:func:`~qifreport.reports.render.band_outline`) and numbered as in the PDF's region table, the
clamps of a restrained inspection, the colour bar, the verdict and what decided it. Pointing
at the part reads out the deviation (mm, signed) of the nearest vertex, the tolerance that
governs it and its band, the B-rep face, the region and the position. Every tolerance zone's
surface, the outlines, the region numbers, the clamps and a subsample of the scan points can
be shown or hidden; the mouse rotates (left), zooms (wheel) and pans (right); the buttons
give the PDF's views A, B, C.

The file works offline from ``file://`` in any browser with WebGL: no server, no network, no
``<script src>`` or stylesheet link. Rendering is three.js (:mod:`qifreport.reports.threejs`,
from the installed trimesh) with a small viewer script of our own
(``qifreport/reports/viewer.js``, package data) for the readout and the toggles. The
geometry travels as base64 typed arrays: positions quantised to uint16 on the part's box
(a step of diagonal / 65535 per axis, 0.006 mm on a 300 mm part: the readout takes the
deviation from the data, never from the positions), colours uint8, deviations float32,
triangles uint16 (uint32 above 65,536 vertices). The sample panel (6,663 vertices) makes a
file of 1.2 MB, of which three.js is 0.64 MB; meshed at 39k vertices (``--max-edge 1``), 2.8 MB.
Nothing is decimated: above about 70k vertices a page exceeds 5 MB.

Opening the page with ``#at=X,Y,Z`` (mm, e.g. ``panel.html#at=30.0,19.3,3.8``, a region's
centroid as the PDF and the QIF give it) picks the part where that point is drawn in view A,
as a click there would.
"""

from __future__ import annotations

import base64
import html
import json
import logging
from importlib import resources
from pathlib import Path

import numpy as np

from qifreport import __version__
from qifreport.metrology.inspection import InspectionResult
from qifreport.qif.writer import Provenance

from .context import clamp_markers, distinct_bands, map_views, vertex_bands
from .kit import (
    FAIL_BG,
    PASS_BG,
    UNSURE_BG,
    fmt_area,
    fmt_band,
    fmt_mm,
    fmt_pct,
    fmt_smm,
    fmt_utc,
    join_names,
)
from .render import (
    GREY,
    OUTLINE,
    band_outline,
    color_scale,
    deviation_colors,
)
from .tables import zone_status
from .threejs import three_js, three_js_origin
from .views import camera_frame

__all__ = [
    "MAX_SCAN_POINTS",
    "PANEL_WIDTH_PX",
    "colour_bar_svg",
    "html_page",
    "viewer_data",
    "write_html",
]

log = logging.getLogger(__name__)

#: width of the side panel (verdict, colour bar, toggles, readout), CSS pixels; the map
#: fills the rest of the window
PANEL_WIDTH_PX = 340
#: the most scan points the page carries (a uniform random subsample, seed 0)
MAX_SCAN_POINTS = 20_000
#: regions listed in the side panel's table (every region is numbered on the map)
REGIONS_LISTED = 30
#: uint16 quantisation levels of the positions
_LEVELS = 65535


def write_html(
    path: Path,
    res: InspectionResult,
    prov: Provenance,
    *,
    face_id: np.ndarray | None = None,
    max_points: int = MAX_SCAN_POINTS,
) -> None:
    """Write the interactive HTML deviation map of an inspection.

    Parameters
    ----------
    path : the file to write (the caller makes it atomic).
    res : the inspection result.  prov : its provenance (part name, files, serial number,
        the B-rep faces' STEP ids).
    face_id : (f,) B-rep face id of each triangle (a STEP nominal), or None (a mesh).
    max_points : most scan points carried (a uniform subsample).
    """
    page = html_page(res, prov, face_id=face_id, max_points=max_points)
    Path(path).write_text(page, encoding="utf-8")
    log.info("HTML viewer: %.0f kB", len(page.encode("utf-8")) / 1024)


def html_page(
    res: InspectionResult,
    prov: Provenance,
    *,
    face_id: np.ndarray | None = None,
    max_points: int = MAX_SCAN_POINTS,
) -> str:
    """The HTML text of :func:`write_html` (one self-contained page)."""
    data = viewer_data(res, prov, face_id=face_id, max_points=max_points)
    scale = data["scale"]
    package = resources.files("qifreport.reports")
    script = package.joinpath("viewer.js").read_text(encoding="utf-8")
    style = package.joinpath("viewer.css").read_text(encoding="utf-8")
    style = style.replace("PANEL_WIDTH", f"{PANEL_WIDTH_PX}px")
    title = f"{prov.part_name}: {res.verdict} (qifreport deviation map)"
    return "\n".join(
        [
            "<!DOCTYPE html>",
            '<html lang="en">',
            "<head>",
            '<meta charset="utf-8">',
            '<meta name="viewport" content="width=device-width, initial-scale=1">',
            f"<title>{_esc(title)}</title>",
            f"<style>\n{style}</style>",
            "</head>",
            '<body data-status="loading">',
            _panel(res, prov, scale, data),
            '<main id="view"><div id="labels"></div>'
            '<div id="readout" aria-live="polite" hidden></div>'
            '<div id="msg" hidden>Loading the deviation map\u2026</div></main>',
            f'<script type="application/json" id="viewer-data">{_json_for_html(data)}</script>',
            f"<script>\n{three_js()}\n</script>",
            f"<script>\n{script}</script>",
            "</body>",
            "</html>",
            "",
        ]
    )


# ------------------------------------------------------------------------------ the data


def viewer_data(
    res: InspectionResult,
    prov: Provenance,
    *,
    face_id: np.ndarray | None = None,
    max_points: int = MAX_SCAN_POINTS,
) -> dict:
    """What the page's script draws, JSON-able: typed arrays as ``{"dtype", "data"}``
    (little-endian, base64), lengths in mm.

    Keys: ``frame`` (``origin``, ``step``: the uint16 positions' grid, mm), ``positions``,
    ``colors`` (uint8 RGB, the PDF's colours), ``deviation`` (float32, NaN unscored),
    ``governing`` (int16 index into ``zones``, -1 none), ``zones`` (per tolerance zone: key,
    label, band, result, its triangles ``index`` and their B-rep ``faces``), ``default_band``,
    ``face_step_ids``, ``outline`` (segment end points), ``regions`` (number, area, peak,
    anchor, vertices), ``markers`` (clamps), ``points`` (the scan subsample), ``views`` (the
    PDF's views A, B, C: direction, up, centre and half extents, mm), ``radius``.
    """
    V = np.asarray(res.V_registered, dtype=np.float64)
    F = np.asarray(res.F, dtype=np.int64)
    n = len(V)
    dev = np.asarray(res.deviation, dtype=np.float64)
    lower, upper = vertex_bands(res)
    scale = color_scale(dev, lower, upper)
    rgb = (deviation_colors(dev, lower, upper, scale) * 255 + 0.5).astype(np.uint8)
    outline = band_outline(V, F, dev, lower, upper).reshape(-1, 3)
    P = _subsample(np.asarray(res.P, dtype=np.float64).reshape(-1, 3), max_points)
    markers = clamp_markers(res)
    M = np.array([np.asarray(p, dtype=np.float64) for _, p in markers]).reshape(-1, 3)
    everything = np.concatenate([V, outline, P, M])
    origin = everything.min(axis=0)
    step = np.maximum(np.ptp(everything, axis=0), 1e-9) / _LEVELS
    centre = 0.5 * (everything.min(axis=0) + everything.max(axis=0))
    index_type = np.uint16 if n <= 65536 else np.uint32

    def quantised(X: np.ndarray) -> dict:
        q = np.clip(np.rint((X - origin) / step), 0, _LEVELS).astype("<u2")
        return _typed(q)

    governing = np.full(n, -1) if res.bands is None else np.asarray(res.bands.governing)
    tol = np.asarray(res.acceptance.tolerance, dtype=np.float64)
    default = float(np.nanmax(tol)) if tol.size else float("nan")
    step_ids = prov.face_step_ids
    return {
        "part": prov.part_name,
        "verdict": res.verdict,
        "n_vertices": n,
        "frame": {"origin": origin.tolist(), "step": step.tolist()},
        "radius": float(np.linalg.norm(everything - centre, axis=1).max() or 1.0),
        "positions": quantised(V),
        "colors": _typed(rgb),
        "deviation": _typed(dev.astype("<f4")),
        "governing": _typed(governing.astype("<i2")),
        "zones": _zone_groups(res, face_id, index_type),
        "default_band": [-default, default] if np.isfinite(default) else None,
        "face_step_ids": None if step_ids is None else [int(s) for s in step_ids],
        "outline": quantised(outline) if len(outline) else None,
        "outline_color": _css(OUTLINE),
        "regions": _regions(res, index_type),
        "markers": [
            {"name": str(name), "position": [float(a) for a in p]}
            for (name, _), p in zip(markers, M, strict=True)
        ],
        "points": {"positions": quantised(P), "shown": len(P), "total": len(res.P)},
        "views": _views(res),
        "scale": scale,
    }


def _zone_groups(res: InspectionResult, face_id: np.ndarray | None, index_type: type) -> list:
    """One group of triangles per tolerance zone laid on the mesh (``res.bands``, in its
    order: ``governing`` indexes it), and one of the triangles no zone covers, if any."""
    F = np.asarray(res.F, dtype=np.int64)
    fid = None if face_id is None else np.asarray(face_id)
    covered = np.zeros(len(F), dtype=bool)
    groups = []
    if res.bands is not None:
        results = {z.zone.key: z for z in res.zones}
        for zone, mask in zip(res.bands.zones, res.bands.tri_masks, strict=True):
            mask = np.asarray(mask, dtype=bool)
            covered |= mask
            z = results.get(zone.key)
            status = "" if z is None else zone_status(res, z)
            groups.append(
                _zone_entry(
                    zone.key,
                    zone.describe(),
                    zone.lower,
                    zone.upper,
                    status,
                    F[mask],
                    None if fid is None else fid[mask],
                    index_type,
                )
            )
    if not covered.all():  # drawn, with no tolerance to read out
        rest = ~covered
        groups.append(
            _zone_entry(
                "",
                "no tolerance",
                np.nan,
                np.nan,
                "",
                F[rest],
                None if fid is None else fid[rest],
                index_type,
            )
        )
    return groups


def _regions(res: InspectionResult, index_type: type) -> list[dict]:
    """The out-of-tolerance regions numbered as in the PDF (1 = the first of the list), each
    with its vertices and an anchor for its number: its vertex nearest to their mean (mm, on
    the registered nominal, so on the region)."""
    V = np.asarray(res.V_registered, dtype=np.float64)
    out = []
    for k, r in enumerate(res.acceptance.regions, start=1):
        idx = np.asarray(r.vertices, dtype=np.int64)
        X = V[idx]
        anchor = X[np.argmin(((X - X.mean(axis=0)) ** 2).sum(axis=1))] if len(X) else r.centroid
        out.append(
            {
                "number": k,
                "area": float(r.area),
                "peak": float(r.peak),
                "anchor": [float(a) for a in anchor],
                "vertices": _typed(idx.astype(index_type)),
            }
        )
    return out


def _views(res: InspectionResult) -> list[dict]:
    """The PDF's views A, B, C (:func:`~qifreport.reports.context.map_views`): direction
    toward the camera, picture up, the centre of the part's extent and its half extents
    across and up the picture, mm."""
    V = np.asarray(res.V_registered, dtype=np.float64)
    out = []
    for k, v in enumerate(map_views(res)):
        r, u, d = camera_frame(v)
        x, y, z = V @ r, V @ u, V @ d
        c = (
            0.5 * (x.min() + x.max()) * r
            + 0.5 * (y.min() + y.max()) * u
            + 0.5 * (z.min() + z.max()) * d
        )
        out.append(
            {
                "name": f"{'ABC'[k]}: {v.name}",
                "direction": d.tolist(),
                "up": u.tolist(),
                "center": c.tolist(),
                "half_width": float(max(np.ptp(x), 1e-6) / 2),
                "half_height": float(max(np.ptp(y), 1e-6) / 2),
            }
        )
    return out


def _zone_entry(
    key: str,
    label: str,
    lower: float,
    upper: float,
    status: str,
    tris: np.ndarray,
    faces: np.ndarray | None,
    index_type: type,
) -> dict:
    face_type = "<u2" if faces is None or not len(faces) or faces.max() < 65536 else "<i4"
    return {
        "key": key,
        "label": label,
        "lower": float(lower) if np.isfinite(lower) else None,
        "upper": float(upper) if np.isfinite(upper) else None,
        "status": status,
        "triangles": len(tris),
        "index": _typed(tris.astype(index_type).ravel()),
        "faces": None if faces is None else _typed(np.asarray(faces).astype(face_type)),
    }


def _subsample(P: np.ndarray, k: int) -> np.ndarray:
    """At most ``k`` of the points ``P`` (m, 3), a uniform random choice (seed 0), in order."""
    if len(P) <= k:
        return P
    keep = np.sort(np.random.default_rng(0).choice(len(P), size=max(k, 0), replace=False))
    return P[keep]


_DTYPES = {"u1": "u8", "u2": "u16", "u4": "u32", "i2": "i16", "i4": "i32", "f4": "f32"}


def _typed(a: np.ndarray) -> dict:
    """A numpy array as ``{"dtype": "u16", "data": base64}`` (little-endian bytes)."""
    a = np.ascontiguousarray(a)
    a = a.astype(a.dtype.newbyteorder("<"), copy=False)
    code = f"{a.dtype.kind}{a.dtype.itemsize}"
    return {"dtype": _DTYPES[code], "data": base64.b64encode(a.tobytes()).decode("ascii")}


def _json_for_html(data: dict) -> str:
    """JSON safe inside ``<script type="application/json">`` (no ``<``, ``>``, ``&``)."""
    text = json.dumps(data, allow_nan=False, separators=(",", ":"))
    return text.replace("<", "\\u003c").replace(">", "\\u003e").replace("&", "\\u0026")


def _css(rgb) -> str:
    return "#" + "".join(f"{int(round(255 * c)):02x}" for c in rgb)


def _esc(text: object) -> str:
    return html.escape(str(text), quote=True)


# --------------------------------------------------------------------------- the panel


def colour_bar_svg(res: InspectionResult, scale: float, width: int = 300) -> str:
    """The colour bar as inline SVG: one row per distinct band (the PDF's rows), the scale
    ``[-scale, +scale]`` mm across ``width`` pixels, ticks at the ends, 0 and the first
    band's limits."""
    bands = distinct_bands(res)
    xs = np.linspace(-scale, scale, 241)
    mids = 0.5 * (xs[1:] + xs[:-1])
    row_h, label_h = 12, 13
    parts, y = [], 0

    def xpos(v: float) -> float:
        return (v + scale) / (2 * scale) * width

    for lo, hi, keys in bands:
        parts.append(
            f'<text x="0" y="{y + 10}" class="cb-label">'
            f"{_esc(join_names(keys, 4))} [{fmt_band(lo)}, {fmt_band(hi)}]</text>"
        )
        y += label_h
        cols = deviation_colors(mids, lo, hi, scale)
        start = 0
        for i in range(1, len(mids) + 1):
            if i == len(mids) or not np.allclose(cols[i], cols[start], atol=1e-3):
                x0, x1 = xpos(xs[start]), xpos(xs[i])
                parts.append(
                    f'<rect x="{x0:.2f}" y="{y}" width="{x1 - x0 + 0.3:.2f}" height="{row_h}" '
                    f'fill="{_css(cols[start])}"/>'
                )
                start = i
        for v in (lo, hi):
            parts.append(
                f'<line x1="{xpos(v):.2f}" x2="{xpos(v):.2f}" y1="{y - 1}" y2="{y + row_h + 1}" '
                'stroke="#111" stroke-width="1.2"/>'
            )
        parts.append(
            f'<rect x="0" y="{y}" width="{width}" height="{row_h}" fill="none" '
            'stroke="#444" stroke-width="0.6"/>'
        )
        y += row_h + 3
    lo, hi, _ = bands[0]
    ticks = [(-scale, f"\u2264{fmt_band(-scale)}"), (0.0, "0"), (scale, f"\u2265{fmt_band(scale)}")]
    ticks += [(lo, fmt_band(lo)), (hi, fmt_band(hi))]
    used: list[tuple[float, float]] = []
    for v, s in ticks:
        x = xpos(v)
        half = 3.2 * len(s) + 3
        if any(not (x + half < a or x - half > b) for a, b in used):
            continue
        used.append((x - half, x + half))
        anchor = "start" if v <= -scale else "end" if v >= scale else "middle"
        parts.append(f'<line x1="{x:.2f}" x2="{x:.2f}" y1="{y - 3}" y2="{y + 1}" stroke="#111"/>')
        parts.append(
            f'<text x="{x:.2f}" y="{y + 11}" text-anchor="{anchor}" class="cb-tick">{_esc(s)}'
            "</text>"
        )
    y += 14
    parts.append(f'<text x="0" y="{y + 9}" class="cb-note">\u2190 sunk</text>')
    parts.append(
        f'<text x="{width}" y="{y + 9}" text-anchor="end" class="cb-note">proud \u2192</text>'
    )
    y += 13
    return (
        f'<svg class="colour-bar" width="{width}" height="{y}" viewBox="0 0 {width} {y}" '
        'role="img" '
        f'aria-label="colour scale, signed deviation in mm">{"".join(parts)}</svg>'
    )


def _verdict_colour(verdict: str) -> str:
    return _css({"PASS": PASS_BG, "FAIL": FAIL_BG}.get(verdict, UNSURE_BG))


def _panel(res: InspectionResult, prov: Provenance, scale: float, data: dict) -> str:
    """The side panel: verdict, inputs, statistics, colour bar, toggles, readout, regions."""
    a, s = res.acceptance, res.vertex_stats
    out = ['<aside id="panel">']
    out.append(f"<h1>{_esc(prov.part_name)}</h1>")
    out.append('<p class="sub">deviation map of the registered nominal</p>')
    out.append(
        f'<div class="verdict" style="background:{_verdict_colour(res.verdict)}">'
        f"{_esc(res.verdict)}</div>"
    )
    # the condition the verdict holds in, who stated it, what the free state gave
    out.append(f'<p class="condition">Judged {_esc(res.condition_text())}.</p>')
    reasons = res.decided_by()
    if reasons:
        items = "".join(f"<li>{_esc(r)}</li>" for r in reasons[:4])
        more = f"<li>+ {len(reasons) - 4} more (see the PDF)</li>" if len(reasons) > 4 else ""
        out.append(f'<ul class="reasons">{items}{more}</ul>')
    rows = [
        ("nominal", Path(prov.nominal_path).name),
        ("scan", Path(prov.scan_path).name),
        ("serial", prov.serial_number or "\u2014"),
        ("inspected", fmt_utc(prov.finished)),
        ("RMS / max |dev|", f"{fmt_mm(s.rms)} / {fmt_mm(s.max_abs)} mm"),
        ("in tolerance", f"{fmt_pct(a.in_tolerance_fraction)} % of the scored area"),
        ("scored", f"{fmt_pct(a.coverage)} % of the nominal area"),
    ]
    out.append(
        '<table class="meta">'
        + "".join(f"<tr><th>{_esc(k)}</th><td>{_esc(v)}</td></tr>" for k, v in rows)
        + "</table>"
    )
    out.append("<h2>Colour scale: signed deviation, mm</h2>")
    out.append(colour_bar_svg(res, scale, width=PANEL_WIDTH_PX - 52))
    out.append(
        '<div class="legend">'
        f'<span class="sw" style="background:{_css(GREY)}"></span>not scanned (unscored) '
        f'<span class="ln" style="background:{_css(OUTLINE)}"></span>band edge '
        '<span class="rn">1</span>region number</div>'
    )
    out.append("<h2>Show</h2>")
    toggles = []
    for i, z in enumerate(data["zones"]):
        status = z["status"]
        badge = f' <b class="st st-{_esc(status.replace("/", ""))}">{_esc(status)}</b>'
        key = z["key"] or "\u2014"
        toggles.append(
            f'<label title="{_esc(z["label"])}"><input type="checkbox" data-layer="zone" '
            f'data-zone="{i}" checked> <b>{_esc(key)}</b> {_esc(z["label"])}'
            f"{badge if status else ''}</label>"
        )
    if data["outline"] is not None:
        toggles.append(
            '<label><input type="checkbox" data-layer="outline" checked> region outlines</label>'
        )
    if data["regions"]:
        toggles.append(
            '<label><input type="checkbox" data-layer="labels" checked> region numbers</label>'
        )
    if data["markers"]:
        toggles.append(
            '<label><input type="checkbox" data-layer="markers" checked> clamps '
            f"({len(data['markers'])})</label>"
        )
    pts = data["points"]
    toggles.append(
        '<label><input type="checkbox" data-layer="points"> scan points '
        f"({pts['shown']:,} of {pts['total']:,})</label>"
    )
    out.append('<div class="toggles">' + "".join(toggles) + "</div>")
    buttons = "".join(
        f'<button type="button" data-view="{i}">{_esc(v["name"])}</button>'
        for i, v in enumerate(data["views"])
    )
    out.append(f'<h2>Views (as in the PDF)</h2><div class="views">{buttons}</div>')
    if a.regions:
        out.append(f"<h2>Out-of-tolerance regions ({len(a.regions)})</h2>")
        body = "".join(
            f"<tr><td>{k}</td><td>{fmt_area(r.area)}</td><td>{fmt_smm(r.peak)}</td></tr>"
            for k, r in enumerate(a.regions[:REGIONS_LISTED], start=1)
        )
        more = len(a.regions) - REGIONS_LISTED
        tail = f'<p class="sub">+ {more} more regions (in the QIF)</p>' if more > 0 else ""
        out.append(
            '<table class="regions"><tr><th>#</th><th>area, mm\u00b2</th><th>peak, mm</th></tr>'
            f"{body}</table>{tail}"
        )
    out.append(
        '<p class="help">Point at the part to read the deviation, tolerance and face there. '
        "Left drag: rotate \u00b7 wheel: zoom \u00b7 right drag: pan \u00b7 R: view A again.</p>"
    )
    out.append(
        f'<p class="foot">qifreport {_esc(__version__)}; the numbers of record are in the QIF '
        f"file and the PDF. Drawn with three.js "
        f'<span id="three-rev"></span> from {_esc(three_js_origin())}.</p>'
    )
    out.append("</aside>")
    return "\n".join(out)
