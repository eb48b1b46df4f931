"""The completion rule: when a flight counts as complete, and how long the scored window runs without completion
(quad_bringup.analysis.metrics, module docstring). Pure Python at import, so the commands' argument parsers can show its
defaults without numpy; its array tests import numpy themselves."""

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class Completion:
    """The course simulator's completion rule (configurable, per vehicle): the one definition that fly's
    live verdict and the report's time_actual_s both use."""
    position_tolerance_m: float = 0.02
    speed_tolerance_mps: float = 0.03
    settle_s: float = 3.0             # without completion the scored window ends at the plan's end + this
    source: str = 'built-in defaults'

    FIELDS = ('position_tolerance_m', 'speed_tolerance_mps', 'settle_s')

    @classmethod
    def for_vehicle(cls, vehicle=None, **overrides) -> 'Completion':
        """The vehicle's `completion:` (vehicle YAML; fields FIELDS) over the defaults, then the overrides that
        are not None (command-line values). Raises ValueError naming the vehicle, the field and the value."""
        values, sources = {}, []
        given = (getattr(vehicle, 'extra', None) or {}).get('completion') if vehicle is not None else None
        if given is not None:
            if not isinstance(given, dict) or set(given) - set(cls.FIELDS):
                raise ValueError(f'vehicle {vehicle.name}: completion = {given!r} may only hold '
                                 f'{", ".join(cls.FIELDS)}')
            values.update(given)
            sources.append(f'vehicle {vehicle.name}')
        chosen = {k: v for k, v in overrides.items() if v is not None}
        if set(chosen) - set(cls.FIELDS):
            raise ValueError(f'completion: unknown field {sorted(set(chosen) - set(cls.FIELDS))[0]!r}')
        values.update(chosen)
        if chosen:
            sources.append('command line')
        from quad_bringup.limits import LIMITS
        for key, value in values.items():
            if key in chosen and (reason := LIMITS[key].check(value)):   # the limits fly applies too
                raise ValueError(reason)
            where = f'vehicle {vehicle.name}: completion.{key}' if key not in chosen else key
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
                    or value < 0 or (value == 0 and key != 'settle_s'):
                raise ValueError(f'{where} = {value!r} must be a finite number > 0' +
                                 (' (>= 0 for settle_s)' if key == 'settle_s' else ''))
        return cls(**{k: float(v) for k, v in values.items()}, source=' + '.join(sources) or 'built-in defaults')

    def describe(self) -> dict:
        return {'position_tolerance_m': self.position_tolerance_m, 'speed_tolerance_mps': self.speed_tolerance_mps,
                'settle_s': self.settle_s, 'source': self.source}

    def plan_arrival_s(self, trajectory) -> float:
        """Time since the trajectory's start after which the plan itself stays within the tolerance
        of its final point (so a loop that passes its end early is not 'complete' at take-off)."""
        import numpy as np

        final = trajectory.position[-1, :3]
        outside = np.linalg.norm(trajectory.position[:, :3] - final, axis=1) > self.position_tolerance_m
        return float(trajectory.times_s[np.nonzero(outside)[0][-1] + 1] - trajectory.times_s[0]
                     if np.any(outside) else 0.0)

    def done(self, elapsed_s, position, velocity, trajectory, arrival_s):
        """Completion test for one sample or arrays of them (positions/velocities on the last axis)."""
        import numpy as np

        final = trajectory.position[-1, :3]
        return ((np.asarray(elapsed_s) >= arrival_s)
                & (np.linalg.norm(np.asarray(position) - final, axis=-1) <= self.position_tolerance_m)
                & (np.linalg.norm(velocity, axis=-1) <= self.speed_tolerance_mps))
