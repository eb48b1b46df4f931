"""The bridge's clock against the emulator (quad_vehicle_emu.mavlink_vehicle, a process of its own speaking MAVLink):
the receive thread feeding the clock while the services and diagnostics read it (no data race)."""

import threading

import numpy as np
import pytest
from bridge_graph import SetpointPublisher, bridge_in_this_process
from std_srvs.srv import SetBool

from quad_bringup.emulated.vehicle_graph import free_udp_port, running_graph

# Telemetry this old puts TIMESYNC (a few ms round trip on loopback) 0.5 s before every arrival, beyond
# quad_bridge.clock's agreement bound (0.25 s), even when a starved receive thread makes TIMESYNC's round trip
# long: the bridge maps time with the arrival minimum filter, whose window of samples (10 s of every timestamped
# message) the diagnostics read. The reproduction used 0.3 s; PX4 SIH's drifting clock did the same.
SLOW_TELEMETRY_S = 0.5
# the bridge died after 55 offboard calls with diagnostics at 1 Hz; here they run flat out, and a diagnostics read
# of the window without the clock's lock raises within the first cycle (each `offboard true` pre-streams 1 s)
OFFBOARD_CYCLES = 10
CALL_TIMEOUT_S = 30.0  # a service the bridge never answers (its executor died) fails the test, not the session


@pytest.fixture
def graph(tmp_path):
    with running_graph(tmp_path) as g:
        yield g


def test_offboard_and_diagnostics_while_telemetry_feeds_the_arrival_filter(graph):
    """A PX4 vehicle whose telemetry is SLOW_TELEMETRY_S old: `offboard` true / false OFFBOARD_CYCLES times while
    another thread publishes the bridge's diagnostics without pause and telemetry keeps arriving; every call is
    answered and accepted, no diagnostics publication raises, the receive thread survives every message."""
    procs, observer = graph
    port = free_udp_port()
    procs.vehicle('px4', f'udpout:127.0.0.1:{port}', extra=('--telemetry-latency-s', str(SLOW_TELEMETRY_S)))
    with bridge_in_this_process(observer, procs.namespace, f'udpin:127.0.0.1:{port}') as bridge:
        observer.wait_for(lambda: observer.link()[1].get('armed') == 'True', 'the bridge to see the armed vehicle')
        observer.wait_for(lambda: observer.link()[1].get('rtt_ms') not in (None, 'nan'), 'a TIMESYNC answer')
        assert observer.link()[1]['clock'] == 'arrival minimum filter', observer.link()[1]
        setpoints = SetpointPublisher(observer)
        observer.wait_for(bridge.streamer.fresh, 'setpoints at the bridge')
        errors, stop = [], threading.Event()

        def diagnostics_flat_out():
            while not stop.is_set():
                try:
                    bridge.publish_diagnostics()
                except Exception as exc:  # noqa: BLE001 - what the test looks for
                    errors.append(repr(exc))
                stop.wait(0.001)

        thread = threading.Thread(target=diagnostics_flat_out, daemon=True)
        thread.start()
        try:
            answers = []
            for _ in range(OFFBOARD_CYCLES):
                for data in (True, False):
                    answers.append(observer.call('offboard', SetBool.Request(data=data), CALL_TIMEOUT_S))
                if errors:
                    break
        finally:
            stop.set()
            thread.join(timeout=5)
            setpoints.stop()
        clock = bridge.telemetry.clock.source
        handler_errors = bridge.client.handler_errors
    print(f'{len(answers)} offboard calls, diagnostics errors {errors[:3]}, clock {clock}, '
          f'receive-thread handler errors {handler_errors}')
    assert not errors, f'diagnostics raised while telemetry arrived: {errors[0]}'
    assert all(a.success for a in answers), [a.message for a in answers if not a.success]
    assert len(answers) == 2 * OFFBOARD_CYCLES
    assert handler_errors == 0
    assert clock == 'arrival minimum filter'


# PX4 SIH's clock ran at 0.984-0.993 of wall time; the emulator's runs at this rate of ours
CLOCK_RATE = 0.985
DRIFT_PPM = 1e6 * (1 / CLOCK_RATE - 1)   # what the bridge should find: +15228 ppm
FLY_S = 16.0         # past the clock's 10 s window: a constant offset over it is 0.15 s wrong at its far end
SETTLED_S = 4.0      # the drift is fitted from 2 s of samples on; scored from here
STAMP_BOUND_S = 0.01


def _boot_clock(log):
    """(boot offset s, rate, wall ns at its origin) from the emulator's `boot clock = ...` line."""
    line = next(x for x in log.splitlines() if 'boot clock = ' in x)
    offset, rest = line.split('boot clock = ')[1].split(' s + ')
    rate, rest = rest.split(' x (wall clock - ')
    return float(offset), float(rate), int(rest.split(' ns)')[0])


@pytest.mark.parametrize('latency_s, source', [(None, 'timesync'), (SLOW_TELEMETRY_S, 'arrival minimum filter')])
def test_odometry_stamps_follow_a_drifting_autopilot_clock(graph, latency_s, source):
    """The emulated PX4's boot clock runs at CLOCK_RATE of ours: every LOCAL_POSITION_NED is stamped within
    STAMP_BOUND_S of the wall-clock time the autopilot measured it (its own time mapped through the emulator's
    clock: the truth), TIMESYNC taken with the drift (default latency); with telemetry SLOW_TELEMETRY_S old
    (TIMESYNC disagrees) the arrival filter's stamps are that latency late, never early; diagnostics give the
    drift."""
    procs, observer = graph
    port = free_udp_port()
    latency = () if latency_s is None else ('--telemetry-latency-s', str(latency_s))
    procs.vehicle('px4', f'udpout:127.0.0.1:{port}', extra=('--clock-rate', str(CLOCK_RATE), *latency))
    with bridge_in_this_process(observer, procs.namespace, f'udpin:127.0.0.1:{port}') as bridge:
        clock, seen = bridge.telemetry.clock, []
        mapped = clock.to_local_ns

        def recording(remote_us, arrival_ns, stream=None):
            local = mapped(remote_us, arrival_ns, stream)
            if stream == 'LOCAL_POSITION_NED':
                seen.append((remote_us, local))
            return local

        clock.to_local_ns = recording
        observer.wait_for(lambda: seen and (seen[-1][0] - seen[0][0]) / 1e6 > FLY_S * CLOCK_RATE,
                          f'{FLY_S} s of odometry')
        link = observer.link()[1]
    boot_offset_s, rate, wall0_ns = _boot_clock(procs.log('vehicle'))
    remote_us, local_ns = np.array(seen, dtype=np.int64).T
    truth_ns = wall0_ns + (remote_us * 1e3 - boot_offset_s * 1e9) / rate
    error_s = (local_ns - truth_ns) / 1e9 - (latency_s or 0.0)
    scored = remote_us - remote_us[0] > SETTLED_S * 1e6 * rate
    print(f'{source}: {scored.sum()} stamps, error {1e3 * error_s[scored].min():.1f} .. '
          f'{1e3 * error_s[scored].max():.1f} ms (latency {latency_s or 0} s taken off); diagnostics clock '
          f'{link.get("clock")}, drift {link.get("clock_drift_ppm")} ppm (truth {DRIFT_PPM:.0f})')
    assert link['clock'] == source
    assert float(link['clock_drift_ppm']) == pytest.approx(DRIFT_PPM, abs=1000.0)
    assert np.all(np.abs(error_s[scored]) < STAMP_BOUND_S)
