"""Hand-made BA bench documents for the report tests: the typed records built from the JSON
layout of bench.json, so a test states only the fields it checks."""

from polarref.bench.ba_records import BenchDoc, ProblemResult, from_json

ENV = {"git_commit": "0" * 40, "git_dirty": False, "cpu_count": 2, "cpu_model": "cpu", "machine": "x86_64",
       "platform": "linux", "python": "3", "versions": {}, "threads": {}, "seeds": {}}
SETTINGS = {"repeat": 1, "target": "t", "converged_rel": 0.01, "ours": {}, "ceres": [],
            "kernels": {"used": "numpy"}}
PROBLEM = {"num_cameras": 2, "num_points": 3, "num_observations": 4, "best_final_cost": 1.0,
           "common_final_cost": 1.0, "target_cost": 1.0, "rows": []}


def problem(**fields) -> ProblemResult:
    return from_json(ProblemResult, {**PROBLEM, **fields})


def doc(problems: list[dict], **fields) -> BenchDoc:
    """A bench document of ``problems`` (each a bench.json problem, defaults filled in)."""
    return from_json(BenchDoc, {"environment": ENV, "settings": SETTINGS,
                                "problems": [{**PROBLEM, **p} for p in problems], **fields})
