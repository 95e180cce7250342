"""``replication.md``: the scorecard of the scene replication (:mod:`polarref.compare.run.replication`)."""

from __future__ import annotations

from polarref.compare.run.replication import ReplicationReport, SceneOutcome


def _scene_name(s: SceneOutcome) -> str:
    return s.folder if s.real else f"{s.folder} (seed {s.seed})"


def _status(s: SceneOutcome) -> str:
    if s.status != "ok":
        return f"{s.status}: {s.reason}"
    dirty = " dirty" if s.git_dirty else ""
    runtime = f", compare {s.runtime_s:.0f} s" if s.runtime_s is not None else ""
    return (f"{s.num_images} images, commit {s.git_commit[:10] or 'unknown'}{dirty}{runtime}"
            + (", reused" if s.reused else ""))


def render(rep: ReplicationReport) -> str:
    p = rep.provenance
    head = ["claim", *(_scene_name(s) for s in rep.scenes), "replicated"]
    lines = [
        "# Replication of the scene-dependent claims", "",
        f"Pre-registered in `polarref/compare/claims/preregistration.toml` `[replication]`, last changed at commit "
        f"{rep.preregistration_commit[:10] or 'unknown'}"
        + (" and modified since (not pre-registered)" if rep.preregistration_modified else "")
        + f"; this run: commit {p.git_commit[:10] or 'unknown'}{' (dirty)' if p.git_dirty else ' (clean)'}.", "",
        f"Measure: {rep.measure}. Each scene is one `polarref compare --preset {rep.preset} --no-claims` run of "
        f"{', '.join(rep.methods)}; the verdicts are the scene (single-run) rules of the scorecard. A claim is "
        "replicated when every scene ran and gave the same verdict. The controlled multi-seed experiments that "
        "decide C3-C5 in the comparison reports are synthetic and do not read the scene.", "",
        "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rep.rows:
        lines.append("| " + " | ".join([r.claim_id, *r.verdicts, r.replicated]) + " |")
    lines += ["", "Scene-independent, not repeated here:", ""]
    lines += [f"- {t}" for t in rep.scene_independent]
    lines += ["", "## Scenes", ""]
    for s in rep.scenes:
        lines.append(f"### {_scene_name(s)}")
        lines += ["", f"`{s.argument}`: {_status(s)}.", ""]
        lines += [f"- {c.claim_id} ({c.verdict}): {c.text}" for c in s.claims]
        lines.append("")
    lines += ["## Provenance", "",
              f"Replication run {rep.wall_s:.0f} s on {p.cpu_count} CPUs ({p.cpu_model}, {p.machine}); load "
              f"average (1/5/15 min) {'/'.join(f'{x:.1f}' for x in rep.load_start)} at the start, "
              f"{'/'.join(f'{x:.1f}' for x in rep.load_end)} at the end (timings on a shared machine are "
              "indicative). Python " + p.python + "; seeds: "
              + ", ".join(f"{k} {v}" for k, v in p.seeds.items()) + ".", ""]
    return "\n".join(lines)
