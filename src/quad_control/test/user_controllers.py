"""User controllers that fail, for test_plugins.py and the graph tests (importable as `user_controllers` with this
folder on the path)."""

import math
import os
import time

import numpy as np

from quad_control.templates.flightsim_controller import SE3Control


class FailsAfter(SE3Control):
    """Flies well, then fails in the way `mode` names once t > 0.5 s."""

    mode = 'raise'

    def update(self, t, state, flat_output):
        out = super().update(t, state, flat_output)
        if t <= 0.5:
            return out
        if self.mode == 'raise':
            raise ZeroDivisionError('division by zero in my controller')
        if self.mode == 'nan':
            return dict(out, cmd_thrust=math.nan)
        if self.mode == 'slow':
            time.sleep(0.3)
            return out
        if self.mode == 'busy':
            until = time.thread_time() + 0.02
            while time.thread_time() < until:
                pass
            return out
        if self.mode == 'keys':
            return {'thrust': out['cmd_thrust'], 'q': out['cmd_q']}
        if self.mode == 'shape':
            return dict(out, cmd_q=np.zeros(3))
        return out


class Raises(FailsAfter):
    mode = 'raise'


class ReturnsNaN(FailsAfter):
    mode = 'nan'


class Slow(FailsAfter):
    mode = 'slow'


class Busy(FailsAfter):
    mode = 'busy'


class WrongKeys(FailsAfter):
    mode = 'keys'


class WrongShape(FailsAfter):
    mode = 'shape'


class FailsOnFile(SE3Control):
    """Flies well until the file named by QUADFLIGHT_TEST_FAIL_FILE exists, then raises (a test's trigger)."""

    def update(self, t, state, flat_output):
        if os.path.exists(os.environ.get('QUADFLIGHT_TEST_FAIL_FILE', '/nonexistent')):
            raise RuntimeError('my controller gave up')
        return super().update(t, state, flat_output)


class MotorOnly:
    """A motor-level controller (what rotorpy's Multirotor flies with control_abstraction='cmd_motor_speeds')."""

    def __init__(self, quad_params):
        self.hover = math.sqrt(quad_params['mass'] * 9.81 / (4 * quad_params['k_eta']))

    def update(self, t, state, flat_output):
        return {'cmd_motor_speeds': np.full(4, self.hover), 'cmd_moment': np.zeros(3)}


class BrokenInit:
    def __init__(self, quad_params):
        self.mass = quad_params['no_such_key']

    def update(self, t, state, flat_output):
        return {}
