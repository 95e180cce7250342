"""Names of the intrinsics groups a BA may refine, and the one parser of ``--refine`` values."""

from __future__ import annotations

REFINE_GROUPS = ("focal", "pp", "dist")


def parse_refine(value) -> tuple[str, ...]:
    """``"focal,pp"`` / sequence -> ordered tuple of groups; "" / "none" / None -> ()."""
    if value is None:
        return ()
    items = value.split(",") if isinstance(value, str) else list(value)
    items = [s.strip().lower() for s in items if s and s.strip()]
    if items in (["none"], []):
        return ()
    if items == ["all"]:
        return REFINE_GROUPS
    bad = [s for s in items if s not in REFINE_GROUPS]
    if bad:
        raise ValueError(f"unknown intrinsics group(s) {', '.join(bad)}; choose from "
                         f"{', '.join(REFINE_GROUPS)} (comma-separated), all or none")
    return tuple(g for g in REFINE_GROUPS if g in items)
