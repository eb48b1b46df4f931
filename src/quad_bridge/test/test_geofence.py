"""The geofence core (quad_bridge.geofence): the stopping point, braking before the wall, the braking setpoint."""

import math

import numpy as np
import pytest

from quad_bridge.geofence import (
    BRAKE,
    BREACH,
    STOPPED_MPS,
    VERTICAL_BRAKE_MPS2,
    Geofence,
    brake_setpoint,
    braking_decel_mps2,
    stopping_point,
)
from quad_common import rotations
from quad_common.types import GRAVITY_MPS2

TILT = math.radians(35.0)
A_H = GRAVITY_MPS2 * math.tan(TILT)   # 6.87 m/s^2


def _fence(**kw):
    return Geofence(True, [-10.0, -10.0, -1.0], [10.0, 10.0, 5.0], max_tilt_rad=TILT, reaction_s=0.3, **kw)


def test_the_stopping_point_is_reaction_plus_braking_distance_along_the_velocity():
    p = stopping_point([0.0, 0.0, 1.0], [3.0, 0.0, 0.0], TILT, 0.3)
    assert p == pytest.approx([0.9 + 9.0 / (2 * A_H), 0.0, 1.0])          # 1.555 m at 3 m/s
    diagonal = stopping_point([0.0, 0.0, 1.0], [3.0, 4.0, 0.0], TILT, 0.0)
    assert np.linalg.norm(diagonal[:2]) == pytest.approx(25.0 / (2 * A_H))
    down = stopping_point([0.0, 0.0, 3.0], [0.0, 0.0, -2.0], TILT, 0.0)
    assert down[2] == pytest.approx(3.0 - 4.0 / (2 * VERTICAL_BRAKE_MPS2))
    assert braking_decel_mps2([3.0, 0.0, 3.0], TILT) == pytest.approx(
        min(A_H * math.sqrt(2), VERTICAL_BRAKE_MPS2 * math.sqrt(2)))   # the tighter limit along the direction
    assert np.all(stopping_point([1.0, 2.0, 3.0], [0.0, 0.0, 0.0], TILT, 0.3) == [1.0, 2.0, 3.0])


def test_braking_starts_where_the_stopping_distance_reaches_the_wall_and_the_breach_comes_once_stopped():
    fence = _fence()
    v = [3.0, 0.0, 0.0]
    assert fence.update([8.4, 0.0, 1.0], v, armed=True, streaming=True) is None     # stops at 9.955
    assert fence.update([8.5, 0.0, 1.0], v, armed=True, streaming=True) == BRAKE    # would stop at 10.055
    assert fence.braking and not fence.breached
    assert fence.update([9.2, 0.0, 1.0], [1.0, 0.0, 0.0], armed=True, streaming=True) is None   # still braking
    assert fence.update([9.5, 0.0, 1.0], [STOPPED_MPS / 2, 0.0, 0.0], armed=True, streaming=True) == BREACH
    assert fence.breach_reason == 'stopped before the wall' and not fence.braking
    assert fence.update([12.0, 0.0, 1.0], v, armed=True, streaming=True) is None     # once until reset
    fence.reset()
    assert fence.update([0.0, 0.0, 1.0], [0.5, 0.0, 0.0], armed=True, streaming=True) is None


def test_without_our_setpoints_the_breach_comes_at_the_predicted_crossing_and_outside_always():
    fence = _fence()
    assert fence.update([8.5, 0.0, 1.0], [3.0, 0.0, 0.0], armed=True, streaming=False) == BREACH
    assert fence.breach_reason == 'its stopping point is outside the box'
    fence.reset()
    assert fence.update([10.5, 0.0, 1.0], [0.0, 0.0, 0.0], armed=True, streaming=True) == BREACH
    assert fence.breach_reason == 'left the box'
    fence.reset()
    assert fence.update([8.5, 0.0, 1.0], [3.0, 0.0, 0.0], armed=True, streaming=True) == BRAKE
    assert fence.update([9.0, 0.0, 1.0], [2.0, 0.0, 0.0], armed=True, streaming=False) == BREACH   # hand-over ended
    assert fence.update([20.0, 0.0, 1.0], [3.0, 0.0, 0.0], armed=False, streaming=True) is None     # disarmed
    assert Geofence(False, [-1, -1, -1], [1, 1, 1]).update([5.0, 0, 0], [3.0, 0, 0], True, True) is None


def test_the_braking_setpoint_decelerates_at_the_limit_against_the_velocity_keeping_yaw():
    yaw = math.radians(30.0)
    sp = brake_setpoint([3.0, 0.0, 0.0], yaw, TILT)
    R = rotations.to_matrix(sp.quaternion)
    accel = sp.specific_force_mps2 * R[:, 2] - [0.0, 0.0, GRAVITY_MPS2]
    assert accel == pytest.approx([-A_H, 0.0, 0.0], abs=1e-9)                      # level, max tilt, against v
    assert math.degrees(math.acos(R[2, 2])) == pytest.approx(35.0)
    assert R[:, 1] @ [math.cos(yaw), math.sin(yaw), 0.0] == pytest.approx(0.0, abs=1e-12)   # position.py's yaw
    down = brake_setpoint([0.0, 0.0, -2.0], 0.0, TILT)
    assert down.specific_force_mps2 == pytest.approx(GRAVITY_MPS2 + VERTICAL_BRAKE_MPS2)


def test_a_point_mass_braked_after_the_reaction_time_stops_inside():
    """The rule and the setpoint agree: at 3 m/s towards the wall, the braking deceleration applied reaction_s
    after BRAKE stops the vehicle inside the box (0.4 m short of the wall at most, from the 50 Hz sampling)."""
    fence, dt = _fence(), 0.02
    p, v, braking_since = np.array([0.0, 0.0, 1.0]), np.array([3.0, 0.0, 0.0]), None
    for k in range(1000):
        action = fence.update(p, v, armed=True, streaming=True)
        if action == BRAKE:
            braking_since = k * dt
        if action == BREACH:
            break
        if braking_since is not None and k * dt >= braking_since + fence.reaction_s:
            v = v + dt * np.array([-braking_decel_mps2(v, TILT), 0.0, 0.0]) if v[0] > 0 else v
        p = p + dt * v
    assert fence.breach_reason == 'stopped before the wall'
    assert 9.6 < p[0] < 10.0
