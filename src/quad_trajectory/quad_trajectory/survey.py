"""A synthetic survey route of any length, for the planner's scale checks (bench_plan, bench_fastest, test_fastest):
legs of 0.4-1.2 m, each turned 0.7 rad from the last, at 1 m height, from a fixed seed (the same route every run)."""

import numpy as np

SEED = 17
LEG_M = (0.4, 1.2)
TURN_RAD = 0.7
HEIGHT_M = 1.0


def survey_waypoints(n_segments: int, seed: int = SEED) -> np.ndarray:
    """(n_segments + 1, 3) waypoints in metres, world ENU, from (0, 0, HEIGHT_M)."""
    rng = np.random.default_rng(seed)
    k = np.arange(n_segments)
    steps = rng.uniform(*LEG_M, (n_segments, 1)) * np.column_stack([np.cos(TURN_RAD * k), np.sin(TURN_RAD * k),
                                                                    np.zeros(n_segments)])
    start = np.array([0.0, 0.0, HEIGHT_M])
    return np.vstack([start, np.cumsum(steps, axis=0) + start])
