"""A DDS write that blocks in the bridge holds neither the setpoint stream nor the keep-alive: the bridge (as its
console script runs it, its `odom` writer keeping all history: test/blocking_odom_bridge.py) hands a PX4 over to
the test's setpoints; then the odometry probe, a reliable reader of `odom`, is stopped, so every odometry write
waits BLOCK_S for its acknowledgement (Fast DDS's max_blocking_time) and fails, while the tap on the wire watches
SET_ATTITUDE_TARGET. rclpy's own publish would hold the interpreter lock through each of those waits."""

import os
import signal
import time

import pytest
from bridge_graph import SetpointPublisher, odom_arrivals, start_odom_probe, tapped_graph
from std_srvs.srv import SetBool

from quad_bringup.emulated.vehicle_graph import ROOT
from quad_common.domains import FASTDDS_PROFILE

BLOCK_S = 2.0            # how long each odometry write waits for the stopped reader (max_blocking_time)
HISTORY = 50             # the odom writer's history (max_samples): 1 s of odometry before writes block
WATCHED_S = 2.5 * BLOCK_S  # the stream is watched this long while the reader is stopped: two blocked writes
# A setpoint stream at 50 Hz beside a loaded machine's stalls (up to ~0.2 s seen in the bridge graph tests, once
# ~1 s of the whole machine at load 11); each blocked write with the interpreter lock held leaves a gap of BLOCK_S.
GAP_BOUND_S = 0.5 * BLOCK_S
HOVER = 0.5

PROFILE = """<?xml version="1.0" encoding="UTF-8" ?>
<profiles xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">
  {participant_and_default_writer}
  <data_writer profile_name="{topic}">
    <qos><reliability><kind>RELIABLE</kind><max_blocking_time><sec>{block_sec}</sec><nanosec>{block_nanosec}</nanosec>
    </max_blocking_time></reliability></qos>
    <topic><resourceLimitsQos><max_samples>{history}</max_samples><max_instances>1</max_instances>
    <max_samples_per_instance>{history}</max_samples_per_instance></resourceLimitsQos></topic>
    <times><heartbeatPeriod><sec>0</sec><nanosec>50000000</nanosec></heartbeatPeriod></times>
  </data_writer>
</profiles>
"""


def blocking_profile(topic: str) -> str:
    """The graph's own Fast DDS profile (quad_common.domains) plus a profile for the `topic` writer: HISTORY
    samples, BLOCK_S of max_blocking_time."""
    own = open(FASTDDS_PROFILE).read()
    body = own[own.index('<participant'):own.index('</profiles>')]
    block_sec, block_nanosec = divmod(round(BLOCK_S * 1e9), 1_000_000_000)
    return PROFILE.format(participant_and_default_writer=body, topic=topic, history=HISTORY, block_sec=block_sec,
                          block_nanosec=block_nanosec)


def _longest_gap_s(stamps, start_s, end_s):
    times = [start_s, *(t for t in stamps if start_s <= t <= end_s), end_s]
    return max(b - a for a, b in zip(times, times[1:]))


@pytest.fixture
def graph(tmp_path):
    with tapped_graph(tmp_path) as (procs, observer, start):
        profile = tmp_path / 'blocking_odom.xml'
        profile.write_text(blocking_profile(f'{procs.namespace}/odom'))
        procs.env.update(FASTRTPS_DEFAULT_PROFILES_FILE=str(profile), FASTDDS_DEFAULT_PROFILES_FILE=str(profile))
        yield procs, observer, start


def test_odometry_writes_that_block_leave_the_setpoint_stream_on_the_wire(graph):
    procs, observer, start = graph
    tap = start('px4', extra=('--offboard-loss-s', '3.0', '--hover-throttle', str(HOVER)),
                script=str(ROOT / 'test' / 'blocking_odom_bridge.py'), hover_throttle=HOVER,
                link_timeout_s=5.0)   # the receive thread reads one datagram batch per blocked write
    probe = start_odom_probe(procs)
    observer.wait_for(lambda: len(odom_arrivals(procs)[0]) > 10, 'the odometry probe to receive odometry')
    publisher = SetpointPublisher(observer)
    try:
        observer.wait_for(lambda: len(tap.setpoints()) > 0 or int(observer.setpoints()[1].get('received', 0)) > 10,
                          'the bridge to hear the setpoints')
        result = observer.call('offboard', SetBool.Request(data=True))
        assert result.success, result.message
        observer.wait_for(lambda: observer.link()[1].get('mode') == 'OFFBOARD', 'mode OFFBOARD')

        stopped_s = time.monotonic()
        os.kill(probe.pid, signal.SIGSTOP)
        try:
            observer.wait_for(lambda: tap.setpoints() and tap.setpoints()[-1][0] > stopped_s + WATCHED_S,
                              f'{WATCHED_S} s of the stream with the odometry reader stopped')
            observer.wait_for(lambda: float(observer.link()[1].get('odom_gap_max_ms', 0)) >= 0.8e3 * BLOCK_S,
                              f'the bridge to report an odometry write that waited {BLOCK_S} s')
        finally:
            os.kill(probe.pid, signal.SIGCONT)
        resumed_s = time.monotonic()
        observer.wait_for(lambda: odom_arrivals(procs)[0][-1] > resumed_s + 0.5,
                          'odometry to flow again once the reader acknowledges')

        gap_s = _longest_gap_s([t for t, _ in tap.setpoints(stopped_s)], stopped_s, stopped_s + WATCHED_S)
        assert gap_s < GAP_BOUND_S, (f'no SET_ATTITUDE_TARGET on the wire for {gap_s:.3f} s while the odometry '
                                     f'writes blocked ({BLOCK_S} s each)')
        assert observer.link()[1].get('mode') == 'OFFBOARD'
        assert observer.setpoints()[1].get('handover') == 'active', observer.setpoints()
    finally:
        publisher.stop()
