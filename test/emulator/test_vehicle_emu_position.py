"""Without GPS the emulated autopilots have a position only while an external-vision pose streams: arming (and,
on ArduPilot, entering a position mode) is refused with the autopilot's own COMMAND_ACK result and STATUSTEXT,
over real UDP MAVLink from a plain pymavlink ground station."""

import threading
import time

ARM, SET_MODE = 400, 176
ACCEPTED, DENIED, FAILED = 0, 2, 4
GUIDED = 4
PREARM = 0x10000000
POSE_RATE_HZ = 30.0


class PoseStream:
    """An external-vision pose at POSE_RATE_HZ from a thread, as the bridge forwards it."""

    def __init__(self, v, flavour):
        self.v, self.flavour, self.stop_event = v, flavour, threading.Event()
        self.thread = threading.Thread(target=self.run, daemon=True)
        self.thread.start()

    def run(self):
        while not self.stop_event.is_set():
            usec = int(time.monotonic() * 1e6)
            if self.flavour == 'px4':   # ODOMETRY, estimator_type VISION (2), as quad_bridge.px4 sends it
                nan21 = [float('nan')] + [0.0] * 20
                self.v.send('odometry', usec, 1, 12, 0.0, 0.0, -1.0, [1.0, 0.0, 0.0, 0.0], float('nan'),
                            float('nan'), float('nan'), float('nan'), float('nan'), float('nan'), nan21, nan21,
                            0, 2, 0)
            else:
                self.v.send('vision_position_estimate', usec, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, [0.0] * 21, 0)
            self.stop_event.wait(1.0 / POSE_RATE_HZ)

    def stop(self):
        self.stop_event.set()
        self.thread.join(timeout=2)


def _texts(v, since):
    """The STATUSTEXTs since `since`, chunks (same non-zero id) joined in chunk_seq order."""
    whole, chunks = [], {}
    for _, m in v.of_type('STATUSTEXT', since):
        if m.id == 0:
            whole.append(m.text)
        else:
            chunks.setdefault(m.id, []).append((m.chunk_seq, m.text))
    return whole + [''.join(t for _, t in sorted(parts)) for parts in chunks.values()]


def _said(v, since, text):
    return v.wait_for(lambda: text in _texts(v, since), f'STATUSTEXT {text!r}', 10.0)


def test_px4_without_gps_arms_only_while_the_vision_pose_streams(vehicles):
    v = vehicles('px4', '--param', 'EKF2_GPS_CTRL=0', position=(0.0, 0.0, 0.0))
    v.wait_message('HEARTBEAT', 0.0)
    since = time.monotonic()
    assert v.command(ARM, 1) == DENIED
    _said(v, since, 'Preflight Fail: No valid local position estimate')
    _said(v, since, 'Arming denied: Resolve system health failures first')
    pose = PoseStream(v, 'px4')
    try:
        v.wait_message('SYS_STATUS', time.monotonic(), lambda m: m.onboard_control_sensors_health & PREARM)
        assert v.command(ARM, 1) == ACCEPTED
        assert v.command(ARM, 0) == ACCEPTED
    finally:
        pose.stop()
    stopped = time.monotonic()
    v.wait_message('SYS_STATUS', stopped, lambda m: not m.onboard_control_sensors_health & PREARM)
    assert time.monotonic() - stopped > 4.0, 'EKF2_NOAID_TOUT: 5 s of dead reckoning before the position is lost'
    assert v.command(ARM, 1) == DENIED


def test_px4_with_gps_arms_without_a_pose(vehicles):
    v = vehicles('px4', position=(0.0, 0.0, 0.0))
    v.wait_message('HEARTBEAT', 0.0)
    assert v.command(ARM, 1) == ACCEPTED


def test_ardupilot_on_external_nav_refuses_guided_until_the_pose_streams(vehicles):
    v = vehicles('ardupilot', '--param', 'EK3_SRC1_POSXY=6', '--param', 'VISO_TYPE=1', position=(0.0, 0.0, 0.0))
    v.wait_message('HEARTBEAT', 0.0)
    since = time.monotonic()
    assert v.command(SET_MODE, 1, GUIDED) == FAILED
    _said(v, since, 'Mode change to GUIDED failed: requires position')
    assert v.mode() != GUIDED
    pose = PoseStream(v, 'ardupilot')
    try:
        assert v.wait_for(lambda: v.command(SET_MODE, 1, GUIDED) == ACCEPTED, 'GUIDED with the pose streaming')
        v.wait_for(lambda: v.mode() == GUIDED, 'mode GUIDED')
        assert v.command(ARM, 1) == ACCEPTED
    finally:
        pose.stop()
