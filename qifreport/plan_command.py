"""The ``qifreport plan PART.step`` command: the part's QIF measurement plan, and its
comparison item by item with another QIF document of the same drawing.

Writes ``<out>/<stem>_plan.qif`` (:mod:`qifreport.qif.plan`), validated against the QIF
schemas (libxml2) before it is published (temp file, then rename); with ``--compare
OTHER.qif`` prints one line per characteristic of either document, paired
(:func:`qifreport.qif.mbd.compare_items`), with the fields that differ. Exit 0 when every
item of the other document has its partner with no difference, 1 otherwise, 2 on bad input.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

from .atomic_io import atomic_write
from .errors import InputError, require_file

__all__ = ["PlanWritten", "add_arguments", "comparison_table", "run", "write_plan"]


def add_arguments(ap: argparse.ArgumentParser) -> None:
    """The arguments of ``qifreport plan``."""
    ap.add_argument("step", type=Path, help="STEP AP242 file with semantic PMI")
    ap.add_argument(
        "--out",
        type=Path,
        default=Path("."),
        metavar="DIR",
        help="output directory (default: current directory); the plan is <stem>_plan.qif",
    )
    ap.add_argument("--force", action="store_true", help="overwrite an existing plan")
    ap.add_argument(
        "--compare",
        type=Path,
        metavar="QIF",
        help="compare the plan's characteristics item by item with this QIF document's "
        "(e.g. another translation of the same drawing): type, tolerance, limits, datums, "
        "material condition, zone; exit 1 when one differs",
    )


def run(args: argparse.Namespace) -> int:
    """Write the plan of ``args.step``; compare it when asked. Returns the exit code."""
    from qifreport.qif.plan import plan_file_name

    step: Path = args.step
    require_file(step, "STEP")
    if args.compare is not None:
        require_file(args.compare, "QIF to compare with")
    out = args.out / plan_file_name(step.stem)
    if out.exists() and not args.force:
        raise InputError(f"{out} exists (use --force to overwrite)")
    written = write_plan(step, out)
    state = written.validation
    print(
        f"plan: {out} ({written.items} characteristics; {state.get('message') or 'not validated'})"
    )
    for w in written.warnings:
        print(f"warning: {w}")
    if args.compare is None:
        return 0
    from qifreport.qif.mbd import compare_items, read_items

    matches = compare_items(read_items(out), read_items(args.compare))
    print(comparison_table(matches, args.compare.name))
    differ = [m for m in matches if m.theirs is not None and (m.ours is None or m.differences)]
    return 1 if differ else 0


@dataclass(frozen=True)
class PlanWritten:
    """A plan written (:func:`write_plan`): its ``path``, the number of characteristics it
    ``items``, its schema ``validation`` (``valid``, ``message``) and the drawing's
    ``warnings`` (sentences)."""

    path: Path
    items: int
    validation: dict
    warnings: tuple[str, ...]


def write_plan(step: Path, out: Path) -> PlanWritten:
    """Write the QIF 3.0 measurement plan of the STEP part ``step`` (its semantic PMI's
    zones, characteristics and datums) to ``out`` (atomically, overwriting)
    (:class:`~qifreport.errors.InputError`: not a readable STEP file)."""
    from qifreport.metrology.acceptance.bands import zones_from_pmi
    from qifreport.metrology.gdt.pmi_plan import specs_from_pmi
    from qifreport.qif.plan import PlanSource, build_plan
    from qifreport.step.reader import STEP_SUFFIXES, read_step

    from .cache import sha256
    from .pipeline import qif_writer

    require_file(step, "STEP")
    if step.suffix.lower() not in STEP_SUFFIXES:
        raise InputError(f"{step.name} is not a STEP file (.stp, .step): a plan needs its PMI")
    part = read_step(step)
    zones, _ = zones_from_pmi(part.pmi, part.face_index(), None)
    src = PlanSource(
        part_name=step.stem,
        nominal_path=str(step),
        nominal_sha256=sha256(step),
        zones=zones,
        plan=specs_from_pmi(part.pmi, part.face_index()),
        datums=list(dict.fromkeys(d.label for d in part.pmi.datums)) if part.pmi else [],
        face_step_ids=part.face_step_ids,
    )
    state: dict = {}
    atomic_write(out, qif_writer(build_plan(src), state))
    n = len(src.plan.specs) + sum(1 for z in zones if z.faces is not None or z.step_id is not None)
    warnings: tuple[str, ...] = ()
    if part.pmi is not None:
        from qifreport.step.plausibility import file_warnings

        warnings = tuple(file_warnings(part.pmi))
    return PlanWritten(out, n, state, warnings)


def comparison_table(matches, other: str) -> str:
    """One line per paired item: ``=`` same, ``~`` differs (the fields), ``-`` only in the
    other document, ``+`` only in the plan."""
    lines = [f"compared with {other}: {len(matches)} item(s)"]
    for m in matches:
        if m.ours is None:
            lines.append(f"  -  {m.theirs.name}: {m.theirs.describe()} (not in the plan)")
        elif m.theirs is None:
            lines.append(f"  +  {m.ours.name}: {m.ours.describe()} (only in the plan)")
        elif m.differences:
            diff = "; ".join(
                f"{d.field} {d.ours} vs {d.theirs}" + (f" ({d.note})" if d.note else "")
                for d in m.differences
            )
            lines.append(f"  ~  {m.theirs.name}: {diff}")
        else:
            lines.append(f"  =  {m.theirs.name}: {m.theirs.describe()}")
    same = sum(1 for m in matches if m.ours and m.theirs and not m.differences)
    theirs = sum(1 for m in matches if m.theirs is not None)
    lines.append(f"{same} of {theirs} item(s) of {other} identical in the plan")
    return "\n".join(lines)
