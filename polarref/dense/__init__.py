"""Dense multi-view stereo on CPU: one module per stage (views, depth, consistency, fusion,
meshing, scoring) and :mod:`polarref.dense.pipeline` running them in order."""
