"""``qifreport pmi``: a table of the semantic PMI read from a STEP file.

One row per geometric tolerance, dimension and datum, in the spirit of the NIST STEP File
Analyzer's semantic PMI report: type, value (mm or deg, as read from the file's own entities),
modifiers, datum reference frame, number of B-rep faces it applies to, and -- for comparison
-- the value OpenCASCADE's XDE returned for the same item (matched by name), so a reader can
see where XDE is wrong. A tolerance's unit basis (flatness per unit area, straightness per unit
length) and maximum, and whether it applies to the whole part, are kept; file-level problems
(records that could not be read or items that refer to nothing read, with the entity id and
why) are rows of their own (``item: 'problem'``), never dropped.
"""

from __future__ import annotations

from collections import defaultdict

from .reader import StepPart

__all__ = [
    "pmi_rows",
    "pmi_table",
]


def _fmt(x: float | None, unit: str = "") -> str:
    if x is None:
        return "?"
    s = f"{x:.6g}"
    return f"{s} {unit}".strip()


def _xde_values(part: StepPart) -> dict[str, list[float | None]]:
    by_name: dict[str, list[float | None]] = defaultdict(list)
    for it in part.xde.items:
        if it.kind == "tolerance":
            by_name[it.name].append(it.value)
    return by_name


def pmi_rows(part: StepPart) -> list[dict]:
    """One dict per PMI item (JSON-ready), tolerances first, then dimensions, then datums."""
    pmi = part.pmi
    rows: list[dict] = []
    if pmi is None:
        return rows
    idx = part.face_index()
    xde = _xde_values(part)
    rows += [_tolerance_row(t, idx, xde) for t in pmi.tolerances]
    rows += [_dimension_row(d, idx) for d in pmi.dimensions]
    rows += [_datum_row(d, idx) for d in pmi.datums]
    rows += [_problem_row(text) for text in pmi.problems]
    return rows


def _face_ids(step_ids, idx: dict[int, int]) -> list[int]:
    """The sorted face ids of the STEP face entity ids in ``idx`` (the others dropped)."""
    return sorted({idx[s] for s in step_ids if s in idx})


def _tolerance_row(t, idx: dict[int, int], xde: dict[str, list]) -> dict:
    """The row of a geometric tolerance; its XDE value is taken off ``xde``'s list of its
    name (one per tolerance of that name, in order)."""
    faces = _face_ids(t.face_step_ids, idx)
    xv = xde.get(t.name) or []
    return {
        "item": "tolerance",
        "step_id": t.step_id,
        "name": t.name,
        "type": t.type,
        "value": t.value,
        "unit": "mm",
        "value_text": t.value_text,
        "zone_form": t.zone_form,
        "modifiers": list(t.modifiers),
        "unequal_displacement": t.unequal_displacement,
        "unit_basis": t.unit_basis,
        "max_value": t.max_value,
        "whole_part": t.whole_part,
        "face_notes": list(t.face_notes),
        "datums": "|".join(d.label for d in sorted(t.datums, key=lambda d: d.precedence)),
        "n_faces": len(faces),
        "faces": faces,
        "xde_value": xv.pop(0) if xv else None,
        "problems": list(t.problems),
    }


def _dimension_row(d, idx: dict[int, int]) -> dict:
    """The row of a dimension (size or location)."""
    faces = _face_ids(d.face_step_ids, idx)
    return {
        "item": "dimension",
        "step_id": d.step_id,
        "name": d.name,
        "type": f"{d.kind} {d.type}".strip(),
        "value": d.nominal,
        "unit": d.unit,
        "lower": d.lower,
        "upper": d.upper,
        "lower_limit": d.lower_limit,
        "upper_limit": d.upper_limit,
        "fit": d.fit,
        "modifiers": list(d.qualifiers),
        "datums": "",
        "n_faces": len(faces),
        "faces": faces,
        "problems": list(d.problems),
        "warnings": list(d.warnings),
    }


def _datum_row(d, idx: dict[int, int]) -> dict:
    """The row of a datum (its targets as modifiers)."""
    faces = _face_ids(d.face_step_ids, idx)
    return {
        "item": "datum",
        "step_id": d.step_id,
        "name": d.label,
        "type": "datum",
        "value": None,
        "unit": "",
        "modifiers": list(d.targets),
        "datums": d.label,
        "n_faces": len(faces),
        "faces": faces,
        "problems": list(d.problems),
    }


def _problem_row(text: str) -> dict:
    """The row of a PMI entity that could not be read."""
    return {
        "item": "problem",
        "step_id": _entity_id(text),
        "name": "",
        "type": "unreadable",
        "value": None,
        "unit": "",
        "modifiers": [],
        "datums": "",
        "n_faces": 0,
        "faces": [],
        "problems": [text],
    }


def _entity_id(text: str) -> int | None:
    """The entity id a problem text starts with (``'#12: ...'``), else ``None``."""
    head = text.split(":", 1)[0].strip()
    return int(head[1:]) if head.startswith("#") and head[1:].isdigit() else None


def pmi_table(part: StepPart) -> str:
    """The PMI rows as a fixed-width text table (pandas), with a header line."""
    import pandas as pd

    pmi = part.pmi
    rows = pmi_rows(part)
    head = (
        f"{part.path.name}: {len(part.faces)} faces, "
        + ("tessellated (triangles, no B-rep); " if part.tessellated else "")
        + f"{part.n_solids} solid(s); "
        f"length unit {pmi.length_unit if pmi else '?'}; "
        f"{sum(r['item'] == 'tolerance' for r in rows)} tolerances, "
        f"{sum(r['item'] == 'dimension' for r in rows)} dimensions, "
        f"{sum(r['item'] == 'datum' for r in rows)} datums (values in mm / deg)"
    )
    n_problems = sum(r["item"] == "problem" for r in rows)
    if n_problems:
        head += f"; {n_problems} file-level problem(s)"
    if not rows:
        return head + "\nno semantic PMI in this file"
    table = []
    for r in rows:
        if r["item"] == "dimension":
            tol = ""
            if r.get("lower") is not None or r.get("upper") is not None:
                tol = f" {_fmt(r.get('upper'))}/{_fmt(r.get('lower'))}"
            elif r.get("lower_limit") is not None:
                tol = f" [{_fmt(r['lower_limit'])}, {_fmt(r.get('upper_limit'))}]"
            value = _fmt(r["value"], r["unit"]) + tol
        elif r["item"] == "tolerance":
            value = _fmt(r["value"], "mm")
            if r.get("unequal_displacement") is not None:
                value += f" UZ {_fmt(r['unequal_displacement'])}"
            if r.get("unit_basis"):
                value += f" / {r['unit_basis']}"
            if r.get("max_value") is not None:
                value += f" max {_fmt(r['max_value'])}"
            if r.get("whole_part"):
                value += " (whole part)"
        else:
            value = ""
        table.append(
            {
                "item": r["item"],
                "#id": r["step_id"],
                "type": r["type"],
                "value": value,
                "modifiers": ",".join(r["modifiers"]),
                "DRF": r["datums"],
                "faces": r["n_faces"],
                "XDE value": "" if r.get("xde_value", None) is None else _fmt(r["xde_value"]),
                "name": r["name"],
                "problems": "; ".join(r["problems"]),
            }
        )
    df = pd.DataFrame(table)
    with pd.option_context("display.max_colwidth", 40, "display.width", 250):
        text = head + "\n" + df.to_string(index=False)
    # an exporter's quirk put right, or one suspected, said whole (the table cuts its columns)
    from .plausibility import file_warnings

    return "\n".join([text, *(f"warning: {w}" for w in file_warnings(pmi))])
