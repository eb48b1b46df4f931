"""fleet_graph reads sim_node's lockstep summary from its log: the stepping time and the longest wait for the
recorder (what a bench reports beside the real-time factor)."""

import math

from quad_bringup.running.fleet_graph import _lockstep_summary

LOG = """[INFO] [1.0] [sim_node]: lockstep: 16 vehicles (cf1, cf2), 1000 Hz physics, disturbances none, world none
[INFO] [9.0] [sim_node]: lockstep: stepped 10.850 s of 16 vehicle(s) in 5.881 s (1.85x real time)
[INFO] [9.1] [sim_node]: lockstep: longest wait for followers 831.3 ms at t = 2.880 s (recorder)
[INFO] [9.2] [sim_node]: lockstep: longest wait for setpoints 7.2 ms at t = 0.010 s (cf1, cf2)
"""


def test_the_stepping_time_and_the_longest_wait_for_the_recorder_are_read_from_the_log(tmp_path):
    log = tmp_path / 'node_host.log'
    log.write_text(LOG)
    assert _lockstep_summary(log, 99.0) == (5.881, 831.3)


def test_a_log_without_the_summary_gives_the_fallback_and_nan(tmp_path):
    log = tmp_path / 'node_host.log'
    log.write_text(LOG.splitlines()[0] + '\n')
    stepping_s, wait_ms = _lockstep_summary(log, 99.0)
    assert stepping_s == 99.0 and math.isnan(wait_ms)
    stepping_s, wait_ms = _lockstep_summary(tmp_path / 'missing.log', 7.0)
    assert stepping_s == 7.0 and math.isnan(wait_ms)
