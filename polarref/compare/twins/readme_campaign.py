"""The README's finding of the twin campaign, generated from its committed cells.

``python -m polarref.compare.twins.readme_campaign reports/paper-tables/campaign README.md`` rewrites
the block between the README's markers: one line per full-size twin of each pinned commit's folder
(reduced sizes are dry runs of the machinery, never a result about the twins), C4 and C5 paired over
the seeds by :func:`polarref.compare.twins.campaign_table.build`. ``tests/compare/twins/
test_readme_campaign.py`` fails when the README and the cells differ.
"""

from __future__ import annotations

import sys
from pathlib import Path

from polarref.compare.twins.campaign_table import (CampaignTable, MethodSummary, TwinCampaign, TwinsRules, build,
                                                   rules)
from polarref.core.markers import rewrite_block

BEGIN = "<!-- campaign-findings: generated from reports/paper-tables/campaign/*/ cells, do not edit by hand -->"
END = "<!-- /campaign-findings -->"
LABELS = (("ours-euclidean", "ours Euclidean"), ("ours-polar", "ours polar"))


def _span(xs, spec: str) -> str:
    lo, hi = format(min(xs), spec), format(max(xs), spec)
    return lo if lo == hi else f"{lo}-{hi}"


def _method(m: MethodSummary | None, label: str) -> str:
    if m is None or not m.minutes:
        return f"{label} not run"
    failed = f", {len(m.failed)} failed" if m.failed else ""
    when = (f"{_span(m.minutes, '.1f')} min per seed (median {m.median_min:.1f}{failed})" if len(m.seeds) > 1
            else f"seed {m.seeds[0]} only, {m.minutes[0]:.1f} min{failed}")
    return (f"{label} {when}, {_span(m.tie_points, ',')} tie points, rotation error "
            f"{_span(m.rotation_error_deg, '.4f')} deg")


def _peer_label(m: MethodSummary) -> str:
    """``pycolmap-incremental-sift-t2`` -> ``pycolmap incremental (2 threads)``."""
    name = m.key.split("-sift")[0].replace("-", " ")
    return name if m.threads is None else f"{name} ({m.threads} thread{'s' if m.threads != 1 else ''})"


def _interval(lo: float | None, hi: float | None, pct) -> str:
    # one paired seed gives no interval: say so rather than print empty bounds
    return "one seed, no interval" if lo is None or hi is None else f"90% CI {pct(lo)} to {pct(hi)}"


def twin_line(t: CampaignTable, tw: TwinCampaign, where: str) -> str:
    by = {m.key: m for m in tw.methods}
    c4, pct = tw.c4, (lambda v: "-" if v is None else f"{100 * v:+.3f}")
    seeds = ", ".join(map(str, c4.seeds)) or "none paired"
    head = f"- `{where}/{t.commit[:12]}/` `{tw.twin}` ({tw.views} views, paired seeds {seeds}): "
    peers = [(k, _peer_label(by[k])) for k in sorted(by) if k.startswith("pycolmap")]
    body = "; ".join(_method(by.get(k), label) for k, label in (*LABELS, *peers))
    if c4.geometric_mean is None:
        return head + body + "; C4 and C5 not tested (no seed with both BAs)."
    ci = "" if c4.lo is None else f", 95% CI {c4.lo:.3f}-{c4.hi:.3f}"
    c5 = ", ".join(f"{s.count.replace('_', ' ')} {pct(s.mean)} % ({_interval(s.lo, s.hi, pct)}, {s.outcome})"
                   for s in tw.c5)
    ba = "" if not c4.ba_ratios else (f"; mapper BA polar/Euclidean x{_span(c4.ba_ratios, '.2f')} (target <= "
                                      f"x{c4.ba_ratio_max:.1f} {'met' if c4.ba_target_met else 'not met'})")
    peak = "" if tw.peak_mb_max is None else f"; peak memory {tw.peak_mb_max:,.0f} MiB"
    return (head + body + f"; C4 **{c4.verdict}** (whole-method speed-up Euclidean/polar x{c4.geometric_mean:.3f}"
            f"{ci}; bar x{c4.bar:.2f}){ba}; C5 **{tw.c5_verdict}** ({c5}){peak}.")


def complete_pin_line(t: CampaignTable, where: str, r: TwinsRules) -> str | None:
    """What C4 and C5 show at scale, for a pin where every twin of the rules ``r`` has their
    seeds all paired; None for any other pin."""
    by = {tw.twin: tw for tw in t.twins}
    if any(n not in by or len(by[n].c4.seeds) < len(r.seeds) for n in r.twins):
        return None
    tws = [by[n] for n in r.twins]
    c4 = ", ".join(f"{tw.twin} {tw.c4.verdict} (x{tw.c4.geometric_mean:.3f}, 95% CI {tw.c4.lo:.3f}-{tw.c4.hi:.3f})"
                   for tw in tws)
    c5 = ", ".join(f"{tw.twin} {tw.c5_verdict}" for tw in tws)
    ba = [x for tw in tws for x in tw.c4.ba_ratios]
    met = sum(x <= r.ba_ratio_max for x in ba)
    return (f"- Complete pin `{where}/{t.commit[:12]}/` (every twin, seeds {', '.join(map(str, r.seeds))} paired): "
            f"C4 {c4}; C5 {c5}; mapper BA polar/Euclidean x{_span(ba, '.2f')}, <= x{r.ba_ratio_max:.1f} on "
            f"{met} of {len(ba)} seeds.")


def findings_block(root: Path) -> str:
    """One line per pin where every twin has all its seeds (:func:`complete_pin_line`), then one
    line per full-size twin per commit folder under ``root`` (folders in name order)."""
    where = "/".join(root.parts[-3:]) if len(root.parts) >= 3 else str(root)
    r = rules()
    full, lines, summary = set(r.twins), [], []  # a reduced size is named "<twin>-<size>"
    for d in sorted(p for p in root.iterdir() if p.is_dir()):
        t = build(d)
        pin = complete_pin_line(t, where, r)
        if pin is not None:
            summary.append(pin)
        lines += [twin_line(t, tw, where) for tw in t.twins if tw.twin in full]
    return "\n".join(summary + lines or ["- no full-size campaign cell committed (not tested)."]) + "\n"


def update_readme(readme: Path, root: Path) -> Path:
    return rewrite_block(readme, BEGIN, END, findings_block(root))


if __name__ == "__main__":  # python -m polarref.compare.twins.readme_campaign reports/paper-tables/campaign README.md
    print(update_readme(Path(sys.argv[2] if len(sys.argv) > 2 else "README.md"),
                        Path(sys.argv[1] if len(sys.argv) > 1 else "reports/paper-tables/campaign")))
