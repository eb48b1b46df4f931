"""The receive thread's telemetry on Python floats against the numpy path it replaced: the same
`odom` and `imu` values from the same MAVLink messages (telemetry.state_from_local_position, imu_flu and
cdr.OdometryPacker / ImuPacker)."""

import os

import numpy as np
import pytest

os.environ['MAVLINK20'] = '1'
from pymavlink.dialects.v20 import ardupilotmega as mavlink  # noqa: E402

from quad_bridge import frames, telemetry  # noqa: E402
from quad_bridge.telemetry_publisher import OdometryFloats  # noqa: E402
from quad_common import rotations  # noqa: E402
from quad_common.ros import cdr  # noqa: E402

STAMP_NS = 1_234_567_890_123


def _messages(seed):
    rng = np.random.default_rng(seed)
    for _ in range(200):
        q = rotations.normalize(rng.normal(size=4))           # w < 0 and w > 0: both signs of the NED->ENU map
        aq = mavlink.MAVLink_attitude_quaternion_message(10, *map(float, q), *map(float, rng.normal(size=3)))
        lpn = mavlink.MAVLink_local_position_ned_message(10, *map(float, rng.normal(scale=20.0, size=6)))
        yield aq, lpn


@pytest.mark.parametrize('seed', [1, 2])
def test_odometry_on_floats_is_the_numpy_paths(seed):
    old, new = cdr.OdometryPacker(), OdometryFloats()
    for aq, lpn in _messages(seed):
        q_ned = frames.from_mavlink_quaternion([aq.q1, aq.q2, aq.q3, aq.q4])
        state = telemetry.state_from_local_position(lpn, q_ned, np.array([aq.rollspeed, aq.pitchspeed, aq.yawspeed]))
        (q, rates), (p, v) = telemetry.attitude_enu(aq), telemetry.local_position_enu(lpn)
        assert (p, v, q, rates) == (tuple(state.position), tuple(state.velocity), tuple(state.quaternion),
                                    tuple(state.body_rates))
        # the same bytes: R^T v on the same floats in both (quad_common.rotations.rotate_back)
        assert new.pack_floats(p, q, rotations.rotate_back(q, v), rates, STAMP_NS) == old.pack(state, STAMP_NS)


@pytest.mark.parametrize('kind', ['HIGHRES_IMU', 'SCALED_IMU', 'RAW_IMU'])
def test_imu_on_floats_is_the_numpy_paths(kind):
    rng = np.random.default_rng(3)
    packer = cdr.ImuPacker()
    for _ in range(100):
        values = rng.normal(scale=10.0, size=6) if kind == 'HIGHRES_IMU' else rng.integers(-2000, 2000, size=6)
        cls = getattr(mavlink, f'MAVLink_{kind.lower()}_message')
        fields = dict(zip(('xacc', 'yacc', 'zacc', 'xgyro', 'ygyro', 'zgyro'), values.tolist()))
        args = [fields.get(f, 0) for f in cls.fieldnames]
        msg = cls(*args)
        acc, gyro = telemetry.imu_flu(msg)
        acc_f, gyro_f = telemetry.imu_flu_floats(msg)
        assert (acc_f, gyro_f) == (tuple(acc), tuple(gyro))
        q = tuple(rotations.normalize(rng.normal(size=4)).tolist())
        assert packer.pack(q, gyro_f, acc_f, STAMP_NS) == packer.pack(np.array(q), gyro, acc, STAMP_NS)
