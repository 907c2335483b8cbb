"""What an inspection said about a perfect scan: the readings a perfect part must not get.

On an exact scan of a part's own B-rep (:func:`qifreport.simulate.brep_scan.exact_scan`)
nothing may FAIL; a characteristic may be NOT ESTABLISHED only where the part is modelled
on a limit of its zone (ISO 14253-1), and NOT MEASURED only with its reason (too little of
the feature seen, a geometry the product does not measure); and every scored vertex lies
within ``4 sigma + U`` of zero (``sigma`` the scan's noise, ``U`` the expanded uncertainty
its zone reports at most).

Read from the inspection's JSON summary (``--json``), so the tests and
``bench/nist_exact_scan.py`` judge the same thing.
"""

from __future__ import annotations

from dataclasses import dataclass, field

__all__ = ["Finding", "PerfectScanReview", "review_perfect_scan"]

#: the statuses a perfect part may get besides PASS, each with its reason
NOT_PASS = ("FAIL", "NOT ESTABLISHED", "INDETERMINATE", "NOT MEASURED", "NOT_MEASURED")


@dataclass(frozen=True)
class Finding:
    """One zone or characteristic that did not PASS on the perfect scan.

    Attributes
    ----------
    key : its key (``T3``, ``D2``, ``G7``).  status : its verdict as the summary gives it.
    what : its description (kind, nominal, limits).  reason : the summary's reason.
    """

    key: str
    status: str
    what: str
    reason: str

    @property
    def failed(self) -> bool:
        """Whether it FAILed."""
        return self.status == "FAIL"


@dataclass
class PerfectScanReview:
    """A perfect scan's summary, reviewed (module docstring).

    Attributes
    ----------
    verdict : the part's verdict.  findings : what did not PASS.
    worst_key : the zone whose largest |deviation| is nearest its bound (or over it).
    worst_dev : that zone's largest |deviation| of a scored vertex, mm.
    worst_bound : its bound ``4 sigma + U`` (``U`` the zone's largest), mm.
    """

    verdict: str
    findings: list[Finding] = field(default_factory=list)
    worst_key: str = ""
    worst_dev: float = 0.0
    worst_bound: float = float("inf")

    @property
    def fails(self) -> list[Finding]:
        """The findings that FAILed."""
        return [f for f in self.findings if f.failed]

    @property
    def vertices_within(self) -> bool:
        """Every zone's scored vertices within ``4 sigma + U`` of zero."""
        return self.worst_dev <= self.worst_bound


def review_perfect_scan(doc: dict, sigma: float) -> PerfectScanReview:
    """Review an inspection's JSON summary ``doc`` of a perfect scan with noise ``sigma`` mm
    (module docstring)."""
    out = PerfectScanReview(verdict=doc["verdict"])
    for z in doc["tolerances"]:
        acc = z.get("acceptance") or {}
        # a zone not judged (REPORTED) is a finding only when it reads out of its band
        reads_in = z["verdict"] == "PASS" or (
            z["verdict"] == "REPORTED" and acc.get("decision") == "PASS"
        )
        if not reads_in:
            reasons = (acc.get("reasons") or []) + (acc.get("uncertain_reasons") or [])
            reasons += (z.get("measured") or {}).get("reasons") or []
            out.findings.append(
                Finding(z["key"], z["verdict"], z["description"], "; ".join(reasons))
            )
        dev = (z.get("deviation") or {}).get("max_abs")
        if dev is None:
            continue
        U = acc.get("uncertainty_max_mm") or 0.0
        bound = 4.0 * sigma + U
        if dev - bound > out.worst_dev - out.worst_bound:
            out.worst_key, out.worst_dev, out.worst_bound = z["key"], dev, bound
    for c in doc["characteristics"]:
        if c["status"] in NOT_PASS:
            what = f"{c['kind']} {c['value'] if c['value'] is not None else '-'}"
            what += f" [{c['lower_limit']}, {c['upper_limit']}] U {c['uncertainty']}"
            out.findings.append(Finding(c["key"], c["status"], what, c["reason"] or ""))
    return out
