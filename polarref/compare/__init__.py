"""Same-input comparison of our SfM/BA forms against pycolmap, with reports and a claims scorecard.

``schema``: metrics.json's records, the one contract of the subpackages. ``run`` (one scene:
orchestration, the one job set, methods, presets, inputs, scoring) writes it with the verdicts of
``claims`` (scorecard, controlled experiments, pre-registration, thresholds); ``report`` draws
pages from it; ``twins`` redoes the paper's Tables 1-3 with run's jobs.
"""
