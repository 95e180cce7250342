"""The README's findings on the committed comparisons, generated from their metrics.json alone.

``python -m polarref.compare.report.readme_findings reports README.md`` rewrites the block between the
README's markers; ``tests/compare/report/test_readme_findings.py`` fails when the README and the JSON differ, so
no figure of a replaced run can stay quoted.
"""

from __future__ import annotations

import sys
from pathlib import Path

from polarref.compare.schema import ClaimResult, MetricsFile, load
from polarref.core.markers import read_block, rewrite_block

BEGIN = "<!-- compare-findings: generated from reports/*/metrics.json, do not edit by hand -->"
END = "<!-- /compare-findings -->"
REPORTS = ("comet-default", "comet-small", "strecha_fountain-P11-small")  # the committed comparisons
BASE, OURS = "ours-euclidean", "ours-polar"


def _fig(claim: ClaimResult, key: str) -> float | None:
    for f in claim.figures:
        if f.key == key:
            return f.value
    return None


def _claim(m: MetricsFile, cid: str) -> ClaimResult | None:
    return next((c for c in m.claims if c.claim_id == cid), None)


def _n(value: float | None, fmt: str) -> str:
    return "not tested" if value is None else format(value, fmt)


def _scene_line(name: str, m: MetricsFile) -> str:
    """Registered views, accuracy, tie points and time of the polar form beside the Euclidean one."""
    env, base, ours = m.environment, m.method(BASE), m.method(OURS)
    ok = sum(r.status == "ok" for r in m.methods)
    head = (f"- `reports/{name}/` ({m.scene.num_images} views, commit {env.git_commit[:7]}"
            f"{' dirty' if env.git_dirty else ''}, {ok}/{len(m.methods)} methods ok): ")
    if base is None or ours is None or base.metrics is None or ours.metrics is None:
        return head + "the Euclidean / polar pair did not both finish (not tested)."
    b, o = base.metrics, ours.metrics
    ratio = (base.runtime_s / ours.runtime_s) if base.runtime_s and ours.runtime_s else None
    rot = (f"; GT rotation error {base.gt.rotation_error_deg_mean:.4f} vs {ours.gt.rotation_error_deg_mean:.4f} deg"
           if base.gt is not None and ours.gt is not None else "")
    verdicts = ", ".join(f"{c.claim_id} {c.verdict}" for c in m.claims)
    return (head + f"registered {b.registered_images}/{b.num_images} (Euclidean) and "
            f"{o.registered_images}/{o.num_images} (polar); reprojection {b.mean_reprojection_error_px:.3f} vs "
            f"{o.mean_reprojection_error_px:.3f} px{rot}; tie points {b.tie_points:,} vs {o.tie_points:,}; "
            f"speed-up of the polar pipeline x{_n(ratio, '.2f')} (one timed run). Verdicts: {verdicts}.")


def _controlled_lines(m: MetricsFile) -> list[str]:
    """The controlled experiments (scene-independent): C3, C4, C5, C7 with their intervals."""
    c3, c4, c5, c7 = (_claim(m, k) for k in ("C3", "C4", "C5", "C7"))
    out = []
    if c3 is not None:
        out.append(f"  C3 ({c3.verdict}): final RMS polar - Euclidean {_n(_fig(c3, 'c_final_d'), '+.4f')} px "
                   f"[{_n(_fig(c3, 'c_final_ci_lo'), '.4f')}, {_n(_fig(c3, 'c_final_ci_hi'), '.4f')}], margin "
                   f"{_n(_fig(c3, 'c_final_margin'), '.4f')}, minimum detectable {_n(_fig(c3, 'c_final_mde'), '.5f')}.")
    if c4 is not None:
        out.append(f"  C4 ({c4.verdict}): BA-only speed-up Euclidean/polar, geometric mean "
                   f"x{_n(_fig(c4, 'c_gm'), '.2f')} [{_n(_fig(c4, 'c_gm_lo'), '.2f')}, {_n(_fig(c4, 'c_gm_hi'), '.2f')}] "
                   f"vs the paper's x{_n(_fig(c4, 'c_paper'), '.1f')} (minimum detectable x{_n(_fig(c4, 'c_mde'), '.2f')})"
                   + _real_part(c4) + ".")
    if c5 is not None:
        out.append(f"  C5 ({c5.verdict}): tie points polar - Euclidean {_n(_fig(c5, 'c5_tp_d'), '+.2f')}% "
                   f"[{_n(_fig(c5, 'c5_tp_ci_lo'), '.2f')}, {_n(_fig(c5, 'c5_tp_ci_hi'), '.2f')}], minimum detectable "
                   f"{_n(_fig(c5, 'c5_tp_mde'), '.2f')}% vs the paper's {_n(_fig(c5, 'c5_tp_paper'), '.2f')}%.")
    if c7 is not None:
        out.append(f"  C7 ({c7.verdict}): mean |corr| in one per-point scene frame, parallax "
                   f"{_n(_fig(c7, 'corr_pa_ray'), '.3f')} vs XYZ {_n(_fig(c7, 'corr_eu_ray'), '.3f')} (world-axis XYZ "
                   f"{_n(_fig(c7, 'corr_eu'), '.3f')}, solver-frame parallax {_n(_fig(c7, 'corr_pa'), '.3f')}).")
    shares = [f"{c.claim_id} {c.invariance.agree_share:.0%}" for c in m.claims if c.invariance is not None]
    if shares:
        out.append(f"  Share of the {len(m.claims[-1].invariance.draws) if m.claims[-1].invariance else 0} "
                   f"moved frames (rotation, translation, scale, units) giving the same verdict: {', '.join(shares)}.")
    return out


def _real_part(c4: ClaimResult) -> str:
    """The real problems' speed-ups of C4 (figures real<i>_gm/_lo/_hi), named by their labels."""
    parts = []
    for f in c4.figures:
        if f.key.startswith("real") and f.key.endswith("_gm"):
            k = f.key[:-3]
            parts.append(f"{f.label.split(':')[0]} x{_n(f.value, '.2f')} [{_n(_fig(c4, k + '_lo'), '.2f')}, "
                         f"{_n(_fig(c4, k + '_hi'), '.2f')}]")
    return ("; real problems: " + ", ".join(parts)) if parts else ""


def findings_block(reports: Path) -> str:
    """The generated lines: one per committed comparison, then the controlled experiments of the
    first (C1, C2 and C6-C8 do not depend on the scene)."""
    loaded = [(name, load(reports / name / "metrics.json")) for name in REPORTS
              if (reports / name / "metrics.json").is_file()]
    lines = [_scene_line(name, m) for name, m in loaded]
    if loaded:
        lines.append(f"- Controlled experiments (from `reports/{loaded[0][0]}/`; the same on every scene):")
        lines += _controlled_lines(loaded[0][1])
    return "\n".join(lines) + "\n"


def readme_block(text: str) -> str | None:
    """What stands between the README's markers (None without them)."""
    return read_block(text, BEGIN, END)


def update_readme(readme: Path, reports: Path) -> Path:
    return rewrite_block(readme, BEGIN, END, findings_block(reports))


if __name__ == "__main__":  # python -m polarref.compare.report.readme_findings reports README.md
    print(update_readme(Path(sys.argv[2] if len(sys.argv) > 2 else "README.md"),
                        Path(sys.argv[1] if len(sys.argv) > 1 else "reports")))
