"""Every threshold a verdict or a table judgement rests on, declared once and before any run.

The claim modules (``claims``, ``claims_experiments``, ``claims_robustness``), the controlled
experiments' success rule and the report's "equivalent" marks all read them from here, so a
reader checks one page and a change cannot leave two copies disagreeing. The controlled
experiments' margins, thresholds, levels and seeds come from the committed pre-registration
(``preregistration.toml``, :mod:`polarref.compare.claims.preregistration`), whose commit every report shows.
"""

from __future__ import annotations

from polarref.compare.claims.preregistration import PREREG

_C3, _C4, _C5, _C6, _C8 = (PREREG.claim(c) for c in ("C3", "C4", "C5", "C6", "C8"))

# ---- scene claims (claims.py) ------------------------------------------------------------------
EXACT_RAD = 1e-9                  # a derivation identity holds "exactly" below this
ROT_EQUIV_DEG, ROT_EQUIV_REL = 0.01, 0.10   # two rotation errors equivalent within max(deg, rel x baseline)
SPEEDUP_CLAIM = _C4.value("speedup_claim")   # the paper's claimed speed-up (scene run and controlled)
TIMING_SLACK = _C4.value("timing_slack")

# ---- controlled experiments (claims_experiments.py, claims_robustness.py) ------------------------
# Equivalence margins (C3) and difference margin (C5):
RMS_MARGIN_PX, RMS_MARGIN_REL = _C3.value("rms_margin_px"), _C3.value("rms_margin_rel")   # final pixel RMS
ROT_MARGIN_DEG, ROT_MARGIN_REL = _C3.value("rot_margin_deg"), _C3.value("rot_margin_rel")  # relative rotation
TIE_MARGIN_REL = _C5.value("tie_margin_rel")    # below the paper's own +0.18 % (Table 1)
ALPHA = 0.05                                    # each one-sided test: a 90 % interval
START_MAX_SUCCESS = _C8.value("start_max_success")
MARGIN = _C6.value("margin")                    # conditioning: "better" is a ratio below 1 - MARGIN
BOOTSTRAP_REPS = int(_C8.value("bootstrap_reps"))   # C8's continuous measure: bootstrap interval
BOOTSTRAP_SEED = int(_C8.value("bootstrap_seed"))
# power (issue 30): minimum detectable effects from the pilot's standard deviations
MDE_ALPHA, MDE_POWER = PREREG.alpha, PREREG.power
PILOT_SD_RMS_PX, PILOT_SD_ROT_DEG = _C3.value("pilot_sd_rms_px"), _C3.value("pilot_sd_rot_deg")
PILOT_SD_LOG_SPEEDUP = _C4.value("pilot_sd_log_speedup")
PAPER_SPEEDUP = _C4.value("paper_effect")
PILOT_SD_TIE_REL, PILOT_SD_OBS_REL = _C5.value("pilot_sd_tie_rel"), _C5.value("pilot_sd_obs_rel")
PAPER_TIE_REL, PAPER_OBS_REL = _C5.value("paper_effect_tie_rel"), _C5.value("paper_effect_obs_rel")

# A controlled BA run succeeds when it reaches the noise floor with correct geometry:
SUCCESS_RMS_NOISE_FACTOR = 2.0   # final pixel RMS below this many times the added noise
SUCCESS_ROT_DEG = 0.5            # mean relative-rotation error below this
SUCCESS_BEARING_DEG = 1.0        # 95th percentile of the bearing error below this
SUCCESS_DEPTH_REL = _C8.value("point_depth_tol")   # low parallax, per point: depth within this (issue 30)

# ---- report tables (report.py) -----------------------------------------------------------------
# "Equivalent" accuracy in the paper's table: 0.482 vs 0.481 px. We call two mean reprojection
# errors equivalent when they differ by at most this many px or this fraction, whichever is larger.
EQUIVALENT_PX = 0.01
EQUIVALENT_REL = 0.02

# ---- twins of the paper's datasets (issue 13's done-when; paper_scale.py) -----------------------
TWIN_REGISTERED_MIN = 0.99       # ours registers at least this fraction of a twin's views
TWIN_ROSETTA_MIN_TIES = 100_000  # ours' tie points on the rosetta twin
TWIN_RUNTIME_TARGET_MIN = 60.0   # whole method, render excluded, on the 2-core machine
