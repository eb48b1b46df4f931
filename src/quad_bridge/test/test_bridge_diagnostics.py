"""mavlink_bridge's diagnostics (quad_bridge.bridge_diagnostics) from one instant's values: names, levels, keys
and their texts."""

from bridge_fakes import Client, Streamer, bridge

from quad_bridge import bridge_diagnostics as bd
from quad_bridge.backend import ParamCheck
from quad_bridge.external_pose import ExternalPoseConfig, ExternalPoseFilter
from quad_bridge.geofence import Geofence
from quad_bridge.px4 import Px4
from quad_common import diagnostics

TELEMETRY = {'clock': 'timesync', 'missing_streams': ''}


def level(status) -> bytes:
    return bytes(status.level)


def values(status) -> dict:
    return {kv.key: kv.value for kv in status.values}


def link(b, check=None, others=(), refusal='', udp=None, realtime_refused=False, telemetry=TELEMETRY):
    s = b.vehicle.snapshot()
    return bd.link_status(s, b.link, dict(telemetry), check, list(others), refusal, udp or {}, b.client,
                          'SCHED_OTHER', realtime_refused)


def test_link_status_names_the_vehicle_and_the_link():
    b = bridge(Px4())
    b.vehicle.heartbeat(Px4().custom_mode('POSCTL'), True, b.now_s())
    b.vehicle.status.params = {'MPC_THR_HOVER': 0.5, 'COM_OF_LOSS_T': 1.0}
    st = link(b, check=ParamCheck(problems=('a', 'b'), notes=('n',)), udp={'vehicle_address': '127.0.0.1:1'})
    assert st.name == 'mavlink_bridge: link' and st.message == 'link up'
    v = values(st)
    assert {k: v[k] for k in ('target_system', 'autopilot', 'mode', 'armed', 'prearm_ready', 'rtt_ms', 'clock',
                              'vehicle_params', 'param_problems', 'param_notes', 'packet_loss_pct', 'losses',
                              'signing', 'realtime', 'vehicle_address', 'other_vehicles', 'link_refusal')} == {
        'target_system': '1', 'autopilot': 'PX4', 'mode': 'POSCTL', 'armed': 'True', 'prearm_ready': '',
        'rtt_ms': 'nan', 'clock': 'timesync', 'vehicle_params': 'COM_OF_LOSS_T=1, MPC_THR_HOVER=0.5',
        'param_problems': 'a; b', 'param_notes': 'n', 'packet_loss_pct': '0.00', 'losses': '0', 'signing': 'off',
        'realtime': 'SCHED_OTHER', 'vehicle_address': '127.0.0.1:1', 'other_vehicles': '', 'link_refusal': ''}
    assert level(st) == diagnostics.WARN          # the parameters contradict ours


def test_link_level_ok_degraded_and_refused():
    b = bridge(Px4())
    assert level(link(b)) == diagnostics.OK
    assert level(link(b, others=(2,))) == diagnostics.WARN
    assert values(link(b, others=(2, 3)))['other_vehicles'] == '2, 3'
    assert level(link(b, realtime_refused=True)) == diagnostics.WARN
    assert level(link(b, udp={'other_senders': '10.0.0.2:5'})) == diagnostics.WARN
    assert level(link(b, telemetry={**TELEMETRY, 'missing_streams': 'ODOMETRY'})) == diagnostics.WARN
    assert level(link(b, refusal='two vehicles')) == diagnostics.ERROR
    b.client = Client()
    b.client.problem = 'signing: the vehicle signs, we have no key'
    st = link(b)
    assert level(st) == diagnostics.ERROR and values(st)['signing'] == b.client.problem
    assert values(link(bridge(Px4(), link_up=False)))['autopilot'] == 'PX4'
    waiting = bridge(None, link_up=False)
    assert values(link(waiting))['autopilot'] == '?' and link(waiting).message == 'link waiting'


def test_setpoints_status_carries_the_hand_over_and_the_counts():
    fence = Geofence(True, [-1, -1, -1], [1, 1, 1])
    counts = {'refused': 0, 'setpoint_source': '/position_controller', 'refused_source': 0, 'stale_events': 0}
    st = bd.setpoints_status('active', 'OFFBOARD', 'hand-over active', 2, True, Streamer(), counts, fence)
    assert st.name == 'mavlink_bridge: setpoints' and st.message == 'hand-over active'
    v = values(st)
    assert list(v) == ['handover', 'target_mode', 'handovers_ended', 'streaming', 'rate_hz', 'received', 'sent',
                       'keepalives', 'superseded', 'refused', 'setpoint_source', 'refused_source', 'stale_events',
                       'geofence_breached', 'geofence_braking']
    assert (v['handover'], v['target_mode'], v['streaming'], v['rate_hz']) == ('active', 'OFFBOARD', 'True', '50.0')
    assert level(st) == diagnostics.OK
    stale = bd.setpoints_status('idle', '', 'x', 3, False, Streamer(), {**counts, 'stale_events': 1}, fence)
    assert level(stale) == diagnostics.WARN and values(stale)['streaming'] == 'False'
    fence.breached = True
    assert level(bd.setpoints_status('idle', '', 'x', 3, False, Streamer(), counts, fence)) == \
        diagnostics.WARN


def test_external_pose_status_warns_with_its_fault():
    ep = ExternalPoseFilter(ExternalPoseConfig())
    st = bd.external_pose_status(ep, 0, 1)
    assert st.name == 'mavlink_bridge: external pose' and st.message == 'forwarding'
    assert level(st) == diagnostics.OK
    assert values(st) == {'frame': 'enu', 'rate_hz': '0.0', 'age_ms': f'{ep.last_age_s * 1e3:.1f}', 'forwarded': '0',
                          'dropped_rate': '0', 'dropped_late': '0', 'fault': '', 'handovers_ended': '1'}
    ep.fault = 'timeout (no pose for 0.5 s)'
    st = bd.external_pose_status(ep, 0, 1)
    assert level(st) == diagnostics.WARN and st.message == values(st)['fault'] == ep.fault
