"""Same-input comparison of our SfM/BA forms against pycolmap, with reports and a claims scorecard.

Modules: ``scenes`` (inputs), ``polarref.peers.colmap_sfm`` (pycolmap pipelines, intrinsics fixed),
``runner`` (isolated, timed jobs), ``jobs`` (what runs in them), ``scoring`` (via
``polarref.metrics``), ``experiments`` + ``claims`` (scorecard), ``schema`` (metrics.json),
``figures`` + ``report`` (built from metrics.json only), ``pipeline`` (orchestration).
"""
