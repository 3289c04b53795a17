"""The crowd benchmark's reference row: visitors round a rover that never moves (no stack)."""

from __future__ import annotations

from benchmarks.bench_crowd import BUILDING, standing_job


def test_a_standing_rover_meets_visitors_and_counts_its_encounters() -> None:
    """Ten visitors round a rover parked by the lobby's tour stop for two minutes: they come
    within a metre of it (encounters are counted as in ``curio sim crowd``) and every
    encounter's minimum is a real distance; with nobody about there are none."""
    job = {"map": "building", "world": str(BUILDING), "kind": "goto", "seed": 100_001,
           "start": (2.5, -1.5, 0.0), "goal": (10.0, 1.0)}
    busy = standing_job({**job, "visitors": 10})
    assert busy["encounters"] > 0
    assert 0 <= busy["encounters_ok"] <= busy["encounters"]
    assert busy["min_person_distance_m"] is not None and busy["min_person_distance_m"] > -0.05
    empty = standing_job({**job, "visitors": 0})
    assert empty["encounters"] == 0
