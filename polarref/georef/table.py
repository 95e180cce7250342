"""The aerotriangulation table (issue 33): records per method, form and variant, read from and
written to JSON; the markdown is generated from the JSON alone, so the two cannot disagree."""

from __future__ import annotations

import dataclasses
import enum
import json
import math
from dataclasses import dataclass
from pathlib import Path

from polarref.core.atomic import atomic_write
from polarref.core.provenance import Provenance
from polarref.georef.adjust import AerotriangulationRecord, CheckPointStats
from polarref.georef.predict import PredictedRMSE

TABLE_FORMAT = "polarref-aerotriangulation/3"
# /2 lacks the realised prediction and the per-draw Monte Carlo; it is read with those absent
READABLE_FORMATS = ("polarref-aerotriangulation/2", TABLE_FORMAT)
PRIORS_ONLY_FACTOR = 1.5   # done-when: priors-only check RMSE within 1.5x of the prediction
GCP_HORIZONTAL_GSD = 2.0   # done-when with 10 control points: horizontal <= 2 GSD
GCP_VERTICAL_GSD = 3.0     # ... and vertical <= 3 GSD


class Variant(enum.StrEnum):
    PRIORS_OFF = "priors off"              # free adjustment, then a similarity onto the prior centres
    PRIORS_ON = "priors on"                # priors inside the mapping and its BAs
    PRIORS_GCPS = "priors + GCPs"          # plus control points in the final adjustment
    GCP_SIMILARITY = "priors + GCP similarity"  # peer: its model moved onto the control points


@dataclass(frozen=True)
class AerotriRow:
    method: str                 # "polarref" or the peer's name
    variant: Variant
    record: AerotriangulationRecord


@dataclass(frozen=True)
class MonteCarlo:
    """Priors-only check-point RMSE pooled over ``draws`` redraws of the prior noise (same
    model, same distribution as the scene's priors), metres."""

    draws: int
    seed: int
    form: str
    rmse: PredictedRMSE     # the adjustment's check points
    linear: PredictedRMSE   # the linear datum model (georef/predict.datum_error) on the same draws
    per_draw: tuple[PredictedRMSE, ...] = ()  # the adjustment's check-point RMSE of each draw

    def exceeding(self, expected: PredictedRMSE, factor: float) -> tuple[int, int]:
        """How many draws have horizontal / vertical RMSE above ``factor`` x ``expected``: how often
        one draw of a correct adjustment fails a single-draw "within factor x" rule."""
        h = sum(d.rmse_horizontal > factor * expected.rmse_horizontal for d in self.per_draw)
        z = sum(d.rmse_z > factor * expected.rmse_z for d in self.per_draw)
        return int(h), int(z)


@dataclass(frozen=True)
class AerotriTable:
    scene: str
    views: int
    registered: tuple[tuple[str, int], ...]  # (method/form label, images registered)
    gsd_m: float
    priors_source: str           # "layout" (independent, synth.uav.gcp_layout) or "scene" (scene.json)
    prior_sigma_m: tuple[float, float, float]
    prior_correlation: float
    attitude_sigma_deg: float | None
    mark_sigma_px: float
    image_sigma_px: float
    seed: int
    predicted: PredictedRMSE
    monte_carlo: MonteCarlo | None
    rows: tuple[AerotriRow, ...]
    notes: tuple[str, ...]
    provenance: Provenance
    prior_sigma_rel: float = 0.0  # the centre priors' sigma grows by this share of the range (comet)
    # the linear datum model fed this scene's own prior errors (georef/predict.datum_error): what
    # the drawn noise predicts for this one draw, where ``predicted`` is its expectation over draws
    realised: PredictedRMSE | None = None

    def to_json(self) -> dict:
        out = dataclasses.asdict(self)
        out["format"] = TABLE_FORMAT
        return out

    @classmethod
    def from_json(cls, d: dict) -> AerotriTable:
        if d.get("format") not in READABLE_FORMATS:
            raise ValueError(f"aerotriangulation table format {d.get('format')!r}, expected {TABLE_FORMAT!r}")
        mc, real = d["monte_carlo"], d.get("realised")
        rows = tuple(AerotriRow(r["method"], Variant(r["variant"]), _record(r["record"])) for r in d["rows"])
        kw = {f.name: d.get(f.name, f.default) for f in dataclasses.fields(cls)}
        kw.update(prior_sigma_m=tuple(d["prior_sigma_m"]), predicted=PredictedRMSE(**d["predicted"]),
                  monte_carlo=None if mc is None else MonteCarlo(mc["draws"], mc["seed"], mc["form"],
                                                                  PredictedRMSE(**mc["rmse"]),
                                                                  PredictedRMSE(**mc["linear"]),
                                                                  tuple(PredictedRMSE(**x) for x in mc.get("per_draw", ()))),
                  realised=None if real is None else PredictedRMSE(**real),
                  rows=rows, notes=tuple(d["notes"]), provenance=Provenance(**d["provenance"]), registered=tuple((k, int(v)) for k, v in d["registered"]))
        return cls(**kw)

    def markdown(self) -> str:
        return "\n".join(_header(self) + _rows(self) + _verdicts(self)) + "\n"

    def write(self, out: Path) -> None:
        """``out/aerotriangulation.json`` and ``.md`` (the markdown generated from the same record)."""
        out.mkdir(parents=True, exist_ok=True)
        atomic_write(out / "aerotriangulation.json", json.dumps(self.to_json(), indent=2) + "\n")
        atomic_write(out / "aerotriangulation.md", self.markdown())


def merge_tables(parts: list[AerotriTable]) -> AerotriTable:
    """One table from parts of one run split by form (scripts/aerotri_table.py --forms), run side
    by side from the same commit on the same scene, layout and priors: rows in the order of the
    parts, the registrations and notes once each, the Monte Carlo of the part that ran it.

    Raises ValueError when the parts disagree on what they share or on their commit."""
    first = parts[0]
    same = ("scene", "views", "gsd_m", "priors_source", "prior_sigma_m", "prior_correlation", "attitude_sigma_deg",
            "mark_sigma_px", "image_sigma_px", "seed", "predicted", "prior_sigma_rel")
    for p in parts[1:]:
        bad = [f for f in same if getattr(p, f) != getattr(first, f)]
        if bad:
            raise ValueError(f"the parts differ in {', '.join(bad)}")
        if (p.provenance.git_commit, p.provenance.git_dirty) != (first.provenance.git_commit, first.provenance.git_dirty):
            raise ValueError("the parts ran from different commits")
    mcs = [p.monte_carlo for p in parts if p.monte_carlo is not None]
    if len(mcs) > 1:
        raise ValueError(f"{len(mcs)} parts ran the Monte Carlo; one may")
    rows = tuple(r for p in parts for r in p.rows)
    keys = [(r.method, r.variant, r.record.form) for r in rows]
    if len(set(keys)) != len(keys):
        raise ValueError("the parts hold the same row twice")
    once = lambda xs: tuple(dict.fromkeys(xs))  # noqa: E731 (order kept, repeats dropped)
    return dataclasses.replace(first, registered=once(x for p in parts for x in p.registered),
                               monte_carlo=mcs[0] if mcs else None, rows=rows,
                               notes=once(n for p in parts for n in p.notes))


def _record(r: dict) -> AerotriangulationRecord:
    c = r["check"]
    return AerotriangulationRecord(**{**r, "check": None if c is None else CheckPointStats(**c)})


def _f(x: float, d: int = 3) -> str:
    return "n/a" if x is None or not math.isfinite(x) else f"{x:.{d}f}"


def _rel(share: float) -> str:
    return f" + {100 * share:g}% of the range to the scene centre" if share else ""


def _header(t: AerotriTable) -> list[str]:
    s = t.prior_sigma_m
    att = "none" if t.attitude_sigma_deg is None else f"{t.attitude_sigma_deg:g} deg"
    p = t.predicted
    lines = [f"# Aerotriangulation: {t.scene}", "",
             f"{t.views} views; GSD {t.gsd_m:.3f} m; pose priors from {t.priors_source}: sigma "
             f"{s[0]:g} / {s[1]:g} / {s[2]:g} m (x / y / z){_rel(t.prior_sigma_rel)}, lag-one correlation {t.prior_correlation:g} "
             f"along the image order, attitude {att}; marks {t.mark_sigma_px:g} px; tie points "
             f"{t.image_sigma_px:g} px; GCP layout seed {t.seed}. Registered: "
             + ", ".join(f"{k} {v}" for k, v in t.registered) + ".", "",
             f"Priors-only prediction (covariance propagation of the prior noise onto the check "
             f"points, georef/predict.py): RMSE X {_f(p.rmse_x)}, Y {_f(p.rmse_y)}, Z {_f(p.rmse_z)}, "
             f"horizontal {_f(p.rmse_horizontal)} m."]
    if t.monte_carlo is not None:
        m = t.monte_carlo
        lines.append(f"Monte Carlo ({m.draws} redraws of the prior noise, seed {m.seed}, {m.form}, priors "
                     f"only, pooled): RMSE X {_f(m.rmse.rmse_x)}, Y {_f(m.rmse.rmse_y)}, Z {_f(m.rmse.rmse_z)}, "
                     f"horizontal {_f(m.rmse.rmse_horizontal)} m; the linear datum model on the same draws: "
                     f"X {_f(m.linear.rmse_x)}, Y {_f(m.linear.rmse_y)}, Z {_f(m.linear.rmse_z)}, horizontal "
                     f"{_f(m.linear.rmse_horizontal)} m.")
    if t.realised is not None:
        r = t.realised
        lines.append(f"This draw's own prior errors through the same linear model (what the noise drawn for this "
                     f"scene predicts): RMSE X {_f(r.rmse_x)}, Y {_f(r.rmse_y)}, Z {_f(r.rmse_z)}, horizontal "
                     f"{_f(r.rmse_horizontal)} m.")
    return lines + [""] + [f"* {n}" for n in t.notes] + [""]


def _rows(t: AerotriTable) -> list[str]:
    out = ["| method | form | variant | control | check | priors | RMSE X | RMSE Y | RMSE Z | RMSE horiz. "
           "| mean 3D | max 3D | sigma0 | horiz. / GSD | Z / GSD |",
           "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for row in t.rows:
        r, c = row.record, row.record.check
        cells = ["n/a"] * 6 if c is None else [_f(c.rmse_x), _f(c.rmse_y), _f(c.rmse_z), _f(c.rmse_horizontal),
                                              _f(c.mean_3d), _f(c.max_3d)]
        gsd = ["n/a"] * 2 if c is None else [_f(c.rmse_horizontal / t.gsd_m, 2), _f(c.rmse_z / t.gsd_m, 2)]
        out.append(f"| {row.method} | {r.form} | {row.variant} | {r.num_control} | "
                   f"{r.num_check if c is None else c.count} | {r.num_priors} | " + " | ".join(cells)
                   + f" | {_f(r.sigma0)} | " + " | ".join(gsd) + " |")
    return out + [""]


def _verdicts(t: AerotriTable) -> list[str]:
    """The issue's done-when, evaluated on the rows of our method."""
    p = t.predicted
    out = ["## Done-when (issue 33), our rows", ""]
    for row in t.rows:
        c = row.record.check
        if row.method != "polarref" or c is None:
            continue
        if row.variant == Variant.PRIORS_ON:
            out.append(_priors_only_verdict(t, row.record.form, c))
        if row.variant == Variant.PRIORS_GCPS:
            h, z = c.rmse_horizontal / t.gsd_m, c.rmse_z / t.gsd_m
            ok = (h <= GCP_HORIZONTAL_GSD and z <= GCP_VERTICAL_GSD and row.record.num_control >= 10
                  and c.count >= 10)
            out.append(f"* {row.record.form}, {row.record.num_control} control / {c.count} check: horizontal "
                       f"{h:.2f} GSD (<= {GCP_HORIZONTAL_GSD:g}), Z {z:.2f} GSD (<= {GCP_VERTICAL_GSD:g}): "
                       f"{'met' if ok else 'NOT met'}")
    if t.monte_carlo is not None:
        m = t.monte_carlo.rmse
        rh, rz = m.rmse_horizontal / p.rmse_horizontal, m.rmse_z / p.rmse_z
        ok = all(1 / PRIORS_ONLY_FACTOR <= r <= PRIORS_ONLY_FACTOR for r in (rh, rz))
        out.append(f"* Monte Carlo vs prediction: horizontal {rh:.2f}x, Z {rz:.2f}x (within "
                   f"{PRIORS_ONLY_FACTOR}x either way: {'met' if ok else 'NOT met'}; one draw of the prior noise "
                   "above can fall far below its expectation, the pooled redraws cannot); vs the linear model on "
                   "the same draws: horizontal "
                   f"{m.rmse_horizontal / t.monte_carlo.linear.rmse_horizontal:.3f}x, "
                   f"Z {m.rmse_z / t.monte_carlo.linear.rmse_z:.3f}x")
    return out


def _priors_only_verdict(t: AerotriTable, form: str, c: CheckPointStats) -> str:
    """One line: the priors-only row against what the prior noise predicts. With the realised
    prediction the rule compares like with like (this draw's errors, within the factor either
    way); the ratio to the expectation over draws is shown beside it, with how often one draw
    of the Monte Carlo exceeds the factor on its own."""
    p = t.predicted
    rh, rz = c.rmse_horizontal / p.rmse_horizontal, c.rmse_z / p.rmse_z
    if t.realised is None:
        ok = rh <= PRIORS_ONLY_FACTOR and rz <= PRIORS_ONLY_FACTOR
        return (f"* {form}, priors only: horizontal {rh:.2f}x, Z {rz:.2f}x the prediction "
                f"(<= {PRIORS_ONLY_FACTOR}x): {'met' if ok else 'NOT met'}")
    ch, cz = c.rmse_horizontal / t.realised.rmse_horizontal, c.rmse_z / t.realised.rmse_z
    ok = all(1 / PRIORS_ONLY_FACTOR <= r <= PRIORS_ONLY_FACTOR for r in (ch, cz))
    line = (f"* {form}, priors only: horizontal {ch:.2f}x, Z {cz:.2f}x what this draw's prior errors predict "
            f"(within {PRIORS_ONLY_FACTOR}x either way): {'met' if ok else 'NOT met'}; {rh:.2f}x, {rz:.2f}x "
            "the expectation over draws")
    m = t.monte_carlo
    if m is not None and m.per_draw:
        h, z = m.exceeding(p, PRIORS_ONLY_FACTOR)
        line += (f" (one draw alone exceeds {PRIORS_ONLY_FACTOR}x the expectation in {h} of {len(m.per_draw)} "
                 f"Monte Carlo redraws horizontally, {z} of {len(m.per_draw)} vertically)")
    return line
