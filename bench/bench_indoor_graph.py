"""Indoor flight through the graph: the 3 m square at 0.8 m/s on the emulated PX4 and ArduPilot (quad_vehicle_emu at
its defaults, `python -m quad_vehicle_emu.mavlink_vehicle`) through the graph
(quad_bringup.emulated.vehicle_graph's processes: real MAVLink over UDP, real DDS; mavlink_bridge, position_controller
with config/control_real.yaml over control.yaml, the real-vehicle default, trajectory_node, the recorder) on a machine
other work shares: the vehicle on the floor, armed, `offboard`, a plan up to the square's first corner (an autopilot
without GPS has no position before the pose streams), then the square, the plan recorded and scored.
Each autopilot with its GPS off and external vision on (PX4: EKF2_EV_CTRL 3, EKF2_HGT_REF 3, EKF2_GPS_CTRL 0,
EKF2_EV_DELAY 0 as docs/bridge.md sets it, flown once the bridge answered 550 of PX4's TIMESYNC requests, when
its filter has converged and maps the pose's stamp; ArduPilot: VISO_TYPE 1, EK3_SRC1_POSXY/VELXY/POSZ/YAW 6), the
emulator's motion-capture stand-in publishing its truth on external/pose (`--mocap-topic external/pose`: 100 Hz,
1 mm RMS noise, 10 ms from capture to message, stamped at the capture instant) and the bridge forwarding it
(`external_pose_enabled: true`). The controller flies from the autopilot's odometry (its estimate, fused from the
forwarded pose) or from the pose itself (`state_source: external_pose`). Beside them the same flights with GPS
(the emulator's default estimate, no external vision; the stand-in still publishing, not forwarded). Truth vs plan:
the recorded external/pose (the truth + 1 mm noise, which adds about 1.7 mm in quadrature) against the plan at its
stamps, over the plan plus 3 s. Odometry vs plan: `quadflight report`'s rmse_m (its scored window: the plan until
completion within the vehicle's 10 cm / 0.1 m/s, else the plan plus 3 s). Load: the 1-minute load average at the
flight's start and at its end (2 cores shared with other sessions). Goal: truth vs plan <= 5 cm for
control_real.yaml."""

import os
import sys
import tempfile
from pathlib import Path

import numpy as np
from std_srvs.srv import SetBool, Trigger

from quad_bringup.analysis.metrics import planned_position
from quad_bringup.analysis.report import load_flight
from quad_bringup.commands.record import ros_arguments
from quad_bringup.emulated.mission_flight import CONTROL, REAL_PROFILE, plan_waypoints, report
from quad_bringup.emulated.offline_chain import SPEED_MPS, SQUARE
from quad_bringup.emulated.vehicle_graph import (
    OFFBOARD_MODE,
    WAIT_S,
    free_udp_port,
    running_graph,
    start_vehicle_graph,
)
from quad_bringup.recording.recorder import DEFAULT_TOPICS, open_bag_reader, typestore
from quad_common import contract
from quad_common.conversions import stamp_to_s, vec3

ROOT = Path(__file__).resolve().parent.parent

EXTERNAL_VISION = {'px4': ('EKF2_EV_CTRL=3', 'EKF2_HGT_REF=3', 'EKF2_GPS_CTRL=0', 'EKF2_EV_DELAY=0'),
                   'ardupilot': ('VISO_TYPE=1', 'EK3_SRC1_POSXY=6', 'EK3_SRC1_VELXY=6', 'EK3_SRC1_POSZ=6',
                                 'EK3_SRC1_YAW=6')}
SETTLE_S = 3.0   # the scored window: the plan plus this
HOVER_M = 0.1    # a plan's end reached: the odometry this close to its last point
EXTERNAL_POSE_STATUS = 'mavlink_bridge: external pose'
PX4_TIMESYNC_ANSWERS = 550   # Timesync's CONVERGENCE_WINDOW (500 round trips under 10 ms) and some slow ones
SOURCES = {   # label: (external vision on, controller parameters)
    'GPS-like estimate (odom, no vision)': (False, {}),
    'autopilot odometry fused from the pose (odom)': (True, {}),
    'the pose directly (state_source external_pose)': (True, {'state_source': 'external_pose'}),
}
FLIGHTS = {'GPS-like estimate (odom, no vision)': 1}   # flights per cell; the others 2
DEFAULT_FLIGHTS = 2


def truth_rmse_m(bag: Path) -> float:
    """RMSE of the recorded motion capture (external/pose) against the plan at each pose's stamp, over the plan's
    start to its end plus SETTLE_S."""
    flight = load_flight(bag)
    ts = typestore()
    reader, _ = open_bag_reader(bag)
    try:
        connections = [c for c in reader.connections if contract.matches(c.topic, contract.EXTERNAL_POSE)]
        if not connections:
            raise ValueError(f'bag {bag}: no {contract.EXTERNAL_POSE} recorded')
        poses = [ts.deserialize_cdr(raw, conn.msgtype) for conn, _, raw in reader.messages(connections=connections)]
    finally:
        reader.close()
    t_s = np.array([stamp_to_s(p.header.stamp) for p in poses])
    position = np.array([vec3(p.pose.position) for p in poses])
    window = (t_s >= flight.traj_start_s) & (t_s <= flight.traj_start_s + flight.trajectory.duration_s + SETTLE_S)
    err = np.linalg.norm(position[window] - planned_position(flight, t_s[window]), axis=1)
    return float(np.sqrt(np.mean(err ** 2)))


def plan_flown(observer, traj, hover, what):
    """Waits for the controller to hold at the plan's end and the odometry within HOVER_M of `hover`."""
    end_s = stamp_to_s(traj.header.stamp) + stamp_to_s(traj.points[-1].time_from_start)
    observer.wait_for(lambda: observer.odom and observer.odom[-1][0] > end_s
                      and observer.controller()[1].get('mode') == 'hold (trajectory ended)', what, WAIT_S)
    observer.wait_for(lambda: np.linalg.norm(np.array(observer.position()) - hover) < HOVER_M,
                      f'{what}: the vehicle within {HOVER_M} m of {hover} ({observer.position()})', WAIT_S)


def fly_cell(flavour: str, vision: bool, controller: dict) -> tuple[float, float, float, float]:
    """(truth RMSE m, odometry RMSE m, load at the start, load at the end) of one flight: the vehicle on the floor
    below the square's first corner (an autopilot without GPS has no position before the pose streams: one
    started in the air descends), armed, `offboard`, a plan up to the corner, then the square (recorded)."""
    with tempfile.TemporaryDirectory() as tmp, running_graph(Path(tmp)) as (procs, observer):
        out_dir = Path(tmp)
        extra = ['--mocap-topic', f'{procs.namespace}/{contract.EXTERNAL_POSE}']   # in the graph's namespace
        for value in EXTERNAL_VISION[flavour] if vision else ():
            extra += ['--param', value]
        try:
            floor = (SQUARE[0][0], SQUARE[0][1], 0.0)
            start_vehicle_graph(procs, flavour, free_udp_port(), position=floor, vehicle_extra=tuple(extra),
                                controller_files=(CONTROL, REAL_PROFILE), bridge={'external_pose_enabled': vision},
                                controller=controller)
            if vision:
                observer.wait_for(lambda: observer.status(EXTERNAL_POSE_STATUS)[0] == 'forwarding',
                                  f'the bridge forwarding the pose ({observer.status(EXTERNAL_POSE_STATUS)})')
            if vision and flavour == 'px4':   # PX4 reads the pose's stamp once its TIMESYNC filter converged
                observer.wait_for(lambda: int(observer.link()[1].get('timesync_requests_answered', 0)) >=
                                  PX4_TIMESYNC_ANSWERS, f'{PX4_TIMESYNC_ANSWERS} TIMESYNC answers', 3 * WAIT_S)
            observer.wait_for(lambda: observer.call('arm', SetBool.Request(data=True)).success, 'arming accepted')
            observer.wait_for(lambda: observer.link()[1].get('armed') == 'True', 'the bridge to see the armed vehicle')
            observer.wait_for(lambda: observer.references, 'the controller to hold position')
            result = observer.call('offboard', SetBool.Request(data=True))
            assert result.success, result.message
            plan_flown(observer, plan_waypoints(procs, observer, [floor, SQUARE[0]], SPEED_MPS), SQUARE[0],
                       'the take-off')
            procs.stop('trajectory')
            load_start = os.getloadavg()[0]
            bag = out_dir / 'bag'
            procs.start('recorder', ['-m', 'quad_bringup.recording.recorder_node',
                                     *ros_arguments(str(bag), list(DEFAULT_TOPICS))])
            traj = plan_waypoints(procs, observer, SQUARE, SPEED_MPS)
            plan_flown(observer, traj, SQUARE[-1], 'the square')
            settle_end_s = observer.odom[-1][0] + SETTLE_S + 1.0
            observer.wait_for(lambda: observer.odom[-1][0] > settle_end_s, 'the settle time')
            assert observer.link()[1].get('mode') == OFFBOARD_MODE[flavour], f'the hand-over ended: {observer.link()}'
            assert observer.controller()[1].get('refused_start_steps') == '0', observer.controller()
            load_end = os.getloadavg()[0]
            procs.stop('recorder')   # SIGTERM: the recorder closes the bag
            result = observer.call('land', Trigger.Request())
            assert result.success, result.message
            metrics, _ = report(bag, out_dir / 'report', procs.env)
        except AssertionError as exc:   # why the hand-over ended, from the bridge's log
            ended = [line for line in procs.log('bridge').splitlines() if 'hand-over ended' in line]
            raise AssertionError(f'{exc}' + (f'; {ended[0].split("]: ")[-1]}' if ended else '')) from exc
        return truth_rmse_m(bag), metrics['rmse_m'], load_start, load_end


def main():
    rows = []
    for flavour in ('px4', 'ardupilot'):
        for label, (vision, controller) in SOURCES.items():
            got = []
            for _ in range(FLIGHTS.get(label, DEFAULT_FLIGHTS)):
                try:
                    got.append(fly_cell(flavour, vision, controller))
                except AssertionError as exc:   # a flight that did not end as planned: a cell, not a crash
                    got.append(str(exc).split('; ')[-1])
                print(f'{flavour} {label}: {got[-1]}', file=sys.stderr)
            flown = [g for g in got if not isinstance(g, str)]
            failed = [g for g in got if isinstance(g, str)]
            note = f' ({len(failed)} of {len(got)} not flown to the end: {"; ".join(failed)})' if failed else ''
            rows.append((f'quad_vehicle_emu {flavour}', label,
                         ' / '.join(f'{100 * g[0]:.1f}' for g in flown) + note,
                         ' / '.join(f'{100 * g[1]:.1f}' for g in flown),
                         ' / '.join(f'{g[2]:.1f}-{g[3]:.1f}' for g in flown)))
    print('## Indoor flight through the graph: motion capture, the emulated autopilots, control_real.yaml\n')
    print(__doc__.replace('\n', ' ').strip() + '\n')
    print('| vehicle | the controller flies | truth vs plan (cm, each flight) | odometry vs plan, report rmse_m '
          '(cm) | load at start-end |')
    print('|---|---|---:|---:|---|')
    for row in rows:
        print('| ' + ' | '.join(row) + ' |')


if __name__ == '__main__':
    main()
