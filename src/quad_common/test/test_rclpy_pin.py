"""The lockstep speed relies on rclpy internals (quad_common.ros.hot_path) and hand-packed CDR (quad_common.ros.cdr),
checked against one rclpy release (hot_path.CHECKED_RCLPY_VERSION). These tests fail loudly, naming the checked
and the installed version, when rclpy is another release or what the fast paths rely on no longer holds."""

import numpy as np
import pytest
import rclpy
from nav_msgs.msg import Odometry
from rclpy.executors import SingleThreadedExecutor
from rclpy.serialization import serialize_message

from quad_common import conversions as conv
from quad_common.ros import cdr, hot_path
from quad_common.ros.testing import isolated_domain
from quad_common.types import AttitudeSetpoint, State

CHECKED = hot_path.CHECKED_RCLPY_VERSION
INSTALLED = hot_path.installed_rclpy_version()
WHY = (f'quad_common.ros.hot_path / quad_common.ros.cdr were checked against rclpy {CHECKED}; rclpy {INSTALLED} is '
       'installed')


def test_installed_rclpy_is_the_checked_release():
    assert INSTALLED == CHECKED, (
        f'{WHY}. Run src/quad_common/test (test_cdr.py, this file) and bench/run sim against it, then set '
        f'CHECKED_RCLPY_VERSION in quad_common/ros/hot_path.py to {INSTALLED}.')


def test_packed_bytes_are_rclpys():
    """The hand-packed layouts against rclpy's own serialization (padding excepted, see test_cdr.py)."""
    state = State(position=np.array([1.0, -2.0, 3.0]), velocity=np.array([0.1, 0.2, -0.3]))
    stamp_ns = 12_345_678_901
    raw = cdr.OdometryPacker().pack(state, stamp_ns)
    expected = serialize_message(conv.state_to_odometry(state, conv.s_to_stamp(stamp_ns * 1e-9)))
    assert len(raw) == len(expected), f'{WHY}: Odometry layout changed ({len(expected)} bytes, packed {len(raw)})'
    setpoint = AttitudeSetpoint(quaternion=np.array([0.0, 0.0, 0.0, 1.0]), specific_force_mps2=9.8,
                                body_rates=np.array([0.1, 0.2, 0.3]))
    raw = cdr.SetpointPacker().pack(setpoint, stamp_ns)
    expected = serialize_message(conv.setpoint_to_imu(setpoint, conv.s_to_stamp(stamp_ns * 1e-9)))
    assert len(raw) == len(expected), f'{WHY}: Imu layout changed ({len(expected)} bytes, packed {len(raw)})'
    assert cdr.imu_to_setpoint(expected).specific_force_mps2 == 9.8, f'{WHY}: Imu layout changed'
    assert cdr.odometry_to_state(serialize_message(conv.state_to_odometry(state, conv.s_to_stamp(1.0))))[0] \
        == 1_000_000_000, f'{WHY}: Odometry header layout changed'


def test_executor_internals_the_hot_path_uses():
    with isolated_domain() as (domain, _):
        ctx = rclpy.Context()
        rclpy.init(context=ctx, domain_id=domain)
        try:
            executor = hot_path.HotPathExecutor(lambda: ([], []), context=ctx)
            for name in ('_guard', '_sigint_gc', '_context', 'wait_for_ready_callbacks'):
                assert hasattr(executor, name), f'{WHY}: Executor.{name} is gone'
            assert hasattr(SingleThreadedExecutor, 'wait_for_ready_callbacks'), f'{WHY}'
            node = rclpy.create_node('pin_probe', context=ctx)
            sub = node.create_subscription(Odometry, 'odom', lambda m: None, 10, raw=True)
            assert hasattr(sub.handle, 'take_message'), f'{WHY}: Subscription handle.take_message is gone'
            fired = []
            guard = node.create_guard_condition(lambda: fired.append(1))
            executor = hot_path.HotPathExecutor(lambda: ([sub], [], [guard]), context=ctx)
            executor.add_node(node)
            guard.trigger()
            for _ in range(50):
                if fired:
                    break
                executor.spin_once(timeout_sec=0.1)
            assert fired, f'{WHY}: a guard condition in the hot wait set did not wake it'
            executor.shutdown()
            node.destroy_node()
        except (AttributeError, TypeError) as exc:
            pytest.fail(f'{WHY}: {type(exc).__name__}: {exc}')
        finally:
            rclpy.shutdown(context=ctx)
