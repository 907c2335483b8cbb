"""The rigid seat of a sheet finished along its rim.

A rigid fit of a compliant, gently curved sheet is decided in its normal direction only: the
sheet can slide along itself at almost no cost, so where the rigid ICP stops along the
surface depends on where it started (the sample shell's conforming scan stopped 1.1 mm and
1.2 degrees from its true placement from the nominal frame, 4.3 mm and 3.7 degrees through
the pose search from any other placement). The virtual fixture then moves the nominal along
its normals only, so a slide is never taken back: the nominal's corner overhangs the
scan's rim and reads as an unmeasured patch, in one placement and not in another.

The rim decides the slide. :func:`seat_on_rim` reads the trim-edge deviation along the
nominal's open rim (:func:`~qifreport.metrology.deviation.edges.edge_deviation`), fits it
with the in-plane slide, the turn about the rim's normal and a scale
(:func:`~qifreport.metrology.deviation.size.size_error`), and moves the scan back by the
slide and the turn (never by the scale: that is the part's size, measured later). A few
rounds, until the move is below :data:`SETTLED`. Only where the rim is seen over at least
:data:`MIN_SEEN` of its length (so on opposite sides): a partial view leaves the pose as the
ICP left it. A closed solid has no open rim and is left alone: its creases hold it.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial.transform import Rotation

from qifreport.metrology.deviation.edges import edge_deviation
from qifreport.metrology.deviation.size import size_error
from qifreport.registration.icp import RigidResult

__all__ = ["MIN_SEEN", "SETTLED", "RimSeat", "seat_on_rim"]

log = logging.getLogger(__name__)

#: mm: a round whose slide (and turn, at the rim's half-extent) moves the rim less than this
#: ends the seat
SETTLED = 0.02
#: the least share of the rim's length seen for the rim to move the seat
MIN_SEEN = 0.5
#: rounds at most (each one edge reading)
_ROUNDS = 4


@dataclass(frozen=True)
class RimSeat:
    """How far the rim moved the rigid seat (:func:`seat_on_rim`).

    Attributes
    ----------
    slide : (3,) mm, the in-plane slide taken back, summed over the rounds.
    turn : degrees, the turn about the rim's normal taken back.
    rounds : edge readings made (0: no open rim, or the rim not seen enough).
    """

    slide: np.ndarray
    turn: float
    rounds: int

    def to_dict(self) -> dict:
        return {
            "slide_mm": [round(float(x), 4) for x in self.slide],
            "turn_deg": round(float(self.turn), 4),
            "rounds": self.rounds,
        }


def seat_on_rim(
    V: np.ndarray,
    F: np.ndarray,
    normals: np.ndarray,
    P: np.ndarray,
    rigid: RigidResult,
    half_width: float = 0.5,
) -> tuple[RigidResult, RimSeat]:
    """The rigid seat ``rigid`` of the scan ``P`` finished along the nominal's open rim.

    Parameters
    ----------
    V : (n, 3) mm, F : (f, 3) the nominal.  normals : (n, 3) its unit vertex normals.
    P : (m, 3) mm, the scan as given (``rigid`` maps it onto the nominal).
    rigid : the rigid ICP's pose.
    half_width : the edge reading's tolerance, mm (which stretches it calls out of
        tolerance; the fitted slide does not depend on it).

    Returns
    -------
    rigid : the pose with the slide and turn taken back (``rigid`` itself when none).
    seat : what was taken back.
    """
    slide, turn, rounds = np.zeros(3), 0.0, 0
    for _ in range(_ROUNDS):
        edges = edge_deviation(V, F, rigid.apply(P), half_width, normals=normals, trim_edges="rim")
        if edges.status != "measured":
            break
        size = size_error(edges)
        if size.seen_fraction < MIN_SEEN or not np.all(np.isfinite(size.translation)):
            break
        rounds += 1
        c, n0 = size.center, size.axes[2]
        back = Rotation.from_rotvec(-size.rotation * n0).as_matrix()
        # x -> back (x - c) + c - t: the scan moved back by the slide and the turn
        rigid = replace(rigid, R=back @ rigid.R, t=back @ (rigid.t - c) + c - size.translation)
        slide, turn = slide + size.translation, turn + float(np.degrees(size.rotation))
        if max(np.linalg.norm(size.translation), abs(size.rotation) * size.half_extent) < SETTLED:
            break
    if rounds:
        log.debug("rim seat: slide %s mm, turn %.3f deg in %d round(s)", slide, turn, rounds)
    return rigid, RimSeat(slide, turn, rounds)
