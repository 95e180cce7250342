"""Benchmarks of whole pipelines: SfM against pycolmap (:mod:`.sfm`, :mod:`.sfm_report`) and the
task executors (:mod:`.executor`). The BA bench is :mod:`polarref.bench.ba`."""
