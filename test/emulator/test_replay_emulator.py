"""`quadflight identify` and `quadflight replay` on a flight recorded as on a real vehicle: the emulated PX4
(quad_vehicle_emu: 0.19 s roll/pitch lag, 20 ms telemetry), mavlink_bridge, position_controller on
control_real.yaml, the recorder, `offboard`, a 3 m square at 1 m/s, `land` (quad_bringup.emulated.twin_check;
bench/bench_twin.py, docs/benchmarks.md). identify finds the emulator's lag and thrust and writes the model;
replay's twin, which flies odometry as old as the flight's controller reported it did, flies within 20 % of the
flight's RMSE and traces the flight; a twin with fresh odometry is no twin. The margin check's verdict holds on the
emulator's attitude structure at the margin it states."""

import pytest

from quad_bringup.emulated import twin_check


@pytest.fixture(scope='module')
def flown(tmp_path_factory):
    tmp = tmp_path_factory.mktemp('px4')
    flight = twin_check.emulator_flight('px4', tmp)
    return tmp, flight.bag


def test_replay_twin_of_an_emulated_px4_flight_within_20_percent(flown):
    tmp, bag = flown
    checked, numbers = twin_check.identify_and_replay(bag, tmp)     # both through the CLI; raises if refused
    r = checked['result']
    for axis in ('roll', 'pitch'):   # the emulator's 1 / 6.5 s quaternion loop + 0.036 s shaping
        assert r[axis]['lag_s'] == pytest.approx(0.19, abs=0.025), r[axis]
    assert r['thrust_scale'] == pytest.approx(1.0, abs=0.01)
    flight, twin, trace = numbers['flight'], numbers['twin'], numbers['trace']
    assert 3.0 < flight < 40.0, numbers
    assert numbers['telemetry'] == 'as the controller reported it', numbers   # its diagnostics, not the recorder's
    assert abs(twin / flight - 1) < 0.2, numbers
    assert trace < twin_check.TRACE_GOAL * flight, numbers
    fresh = twin_check.fresh_twin(bag, tmp / 'model.yaml')
    assert fresh['twin'] < 0.6 * flight and fresh['trace'] > 2 * trace, fresh   # fresh odometry: no twin


def test_the_margin_check_matches_the_emulator_at_its_stated_margin(flown):
    _, bag = flown
    verdicts = {label: (refusal is None, emu.settled) for label, _, refusal, emu in twin_check.margin_rows(bag)}
    assert verdicts['control_real.yaml (kp 2 / kd 2.5)'] == (True, True)    # accepted, settles
    assert verdicts['kp 8 / kd 4'] == (False, False)                        # refused, oscillates
    assert all(accepted == settled for accepted, settled in verdicts.values()), verdicts
