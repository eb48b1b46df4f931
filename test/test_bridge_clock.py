"""The bridge's clock against the emulator (quad_vehicle_emu.mavlink_vehicle, a process of its own speaking MAVLink):
issue 28.1, the receive thread feeding the clock while the services and diagnostics read it (no data race)."""

import threading

import pytest
from bridge_graph import SetpointPublisher, bridge_in_this_process, free_udp_port, running_graph
from std_srvs.srv import SetBool

# Telemetry this old puts TIMESYNC (a few ms round trip on loopback) 0.5 s before every arrival, beyond
# quad_bridge.clock's agreement bound (0.25 s), even when a starved receive thread makes TIMESYNC's round trip
# long: the bridge maps time with the arrival minimum filter, whose window of samples (10 s of every timestamped
# message) the diagnostics read. The reproduction used 0.3 s; PX4 SIH's drifting clock did the same.
SLOW_TELEMETRY_S = 0.5
OFFBOARD_CYCLES = 100  # issue 28: the bridge died after 55 offboard calls, diagnostics at 1 Hz; here they run flat out
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
