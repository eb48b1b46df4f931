"""mavlink_bridge's diagnostics (no rclpy): the `link`, `setpoints` and `external pose` statuses, each a function
of what the bridge knows at one instant; the levels come from quad_bridge.supervision."""

from quad_bridge.parameters import NAME
from quad_bridge.supervision import link_level, setpoints_level
from quad_common import diagnostics


def link_status(s, link, telemetry: dict, check, others: list, refusal: str, udp: dict, client, realtime: str,
                realtime_refused: bool):
    """s: a VehicleStatus snapshot; link: quad_bridge.link.LinkState; telemetry: TelemetryPublisher.info; check:
    the vehicle parameter check (None before the first read); others: other vehicles' system ids; refusal: why no
    vehicle on the link may be commanded, or ''; udp: the udpin link's report; client: the MavlinkClient (signing,
    bad_data, handler_errors)."""
    signing_problem = client.signing_problem()
    level = link_level(link.state, bool(telemetry['missing_streams'] or (check and check.problems) or others
                                        or realtime_refused or udp.get('other_senders')),
                       bool(refusal or signing_problem))
    return diagnostics.status(f'{NAME}: link', level, f'link {link.state}', {
        'target_system': s.system, 'autopilot': s.backend.name if s.backend else '?', 'mode': s.mode,
        'armed': s.armed, 'prearm_ready': '' if s.prearm_ready is None else s.prearm_ready,
        'rtt_ms': f'{s.rtt_ms:.2f}', **telemetry,
        'vehicle_params': ', '.join(f'{k}={v:g}' for k, v in sorted(s.params.items())),
        'param_problems': '; '.join(check.problems) if check else '',
        'param_notes': '; '.join(check.notes) if check else '',
        'packet_loss_pct': f'{link.packet_loss_pct():.2f}', 'losses': link.losses,
        'reconnects': link.reconnects, 'bad_data': client.bad_data,
        'handler_errors': client.handler_errors, 'other_vehicles': ', '.join(map(str, others)),
        'link_refusal': refusal, 'signing': signing_problem or ('on' if client.signing else 'off'),
        'realtime': realtime, **udp})


def setpoints_status(phase: str, target: str, reason: str, ended: int, streaming: bool, streamer, counts: dict,
                     geofence):
    """The hand-over (phase, target mode, why, hand-overs ended), whether setpoints go out, the streamer's counts
    (quad_bridge.setpoint_stream.SetpointStreamer), the setpoint path's counts (with stale_events) and the
    geofence."""
    level = setpoints_level(counts['stale_events'], geofence.breached, counts.get('refused_source', 0))
    return diagnostics.status(f'{NAME}: setpoints', level, reason, {
        'handover': phase, 'target_mode': target, 'handovers_ended': ended,
        'streaming': streaming, 'rate_hz': f'{streamer.rate_hz():.1f}',
        'received': streamer.received, 'sent': streamer.sent_total, 'keepalives': streamer.keepalives,
        'superseded': streamer.superseded, **counts,
        'geofence_breached': geofence.breached, 'geofence_braking': geofence.braking})


def external_pose_status(ep, now_ns: int, handovers_ended: int):
    """ep: the quad_bridge.external_pose.ExternalPoseFilter; WARN while it reports a fault."""
    return diagnostics.status(
        f'{NAME}: external pose', diagnostics.WARN if ep.fault else diagnostics.OK, ep.fault or 'forwarding',
        {'frame': ep.config.frame, 'rate_hz': f'{ep.rate_hz(now_ns):.1f}',
         'age_ms': f'{ep.last_age_s * 1e3:.1f}', 'forwarded': ep.forwarded, 'dropped_rate': ep.dropped_rate,
         'dropped_late': ep.dropped_late, 'fault': ep.fault or '', 'handovers_ended': handovers_ended})
