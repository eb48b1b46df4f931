"""A mission flown as on a real vehicle, against quad_vehicle_emu: the emulated autopilot hovering where it took
off, mavlink_bridge, position_controller with a control profile (the launch files' control_real.yaml by default),
the recorder (`quadflight record`'s node), `offboard`, trajectory_node with the waypoints, `land` after the plan's
end plus the vehicle's settle time, the recorder stopped, then `quadflight report BAG --vehicle VEHICLE`.

Flown through quad_bringup.emulated.vehicle_graph's processes; used by the bridge report test
(test/bridge/test_bridge_report.py) and the bridge benches (bench/bench_bridge_flight.py: the flight table of
docs/bridge.md; bench/bench_twin.py)."""

import json
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

from std_srvs.srv import Trigger

from quad_bringup.analysis.metrics import Completion
from quad_bringup.emulated.vehicle_graph import (
    OFFBOARD_MODE,
    ROOT,
    VEHICLE_FILE,
    enter_offboard,
    free_udp_port,
    start_vehicle_graph,
)
from quad_common.conversions import stamp_to_s
from quad_common.vehicle import load_vehicle

CONTROL = str(ROOT / 'config' / 'control.yaml')
REAL_PROFILE = str(ROOT / 'config' / 'control_real.yaml')


@dataclass
class MissionFlight:
    metrics: dict          # the report's metrics.json
    report_md: str
    trajectory_points: int
    bag: Path


def plan_waypoints(procs, observer, waypoints, speed_mps: float):
    """trajectory_node planning `waypoints` (ENU, m) at speed_mps, started 1 s after it is published; returns that
    plan once the observer hears it (not one heard before)."""
    observer.forget_trajectory()
    flat = ','.join(str(float(c)) for wp in waypoints for c in wp)
    procs.start('trajectory', ['-m', 'quad_trajectory.trajectory_node', '--ros-args', '-p', f'waypoints:=[{flat}]',
                               '-p', f'speed_mps:={speed_mps}', '-p', 'start_delay_s:=1.0',
                               '-p', f'vehicle_file:={VEHICLE_FILE}'])
    observer.wait_for(lambda: observer.trajectory is not None, 'the trajectory')
    return observer.trajectory


def fly_mission(procs, observer, out_dir: Path, flavour: str, waypoints, speed_mps: float,
                profile: str | None = REAL_PROFILE, vehicle_extra=(), bridge_params=None, controller_params=None,
                wait_s: float = 180.0) -> MissionFlight:
    """Flies `waypoints` (ENU, m; the vehicle starts hovering at the first) and returns the report of the bag."""
    out_dir = Path(out_dir)
    bag = out_dir / 'bag'
    start_vehicle_graph(procs, flavour, free_udp_port(), position=waypoints[0], vehicle_extra=vehicle_extra,
                        controller_files=(CONTROL, profile) if profile else (CONTROL,),
                        bridge={'autopilot': flavour, **(bridge_params or {})}, controller=controller_params)
    from quad_bringup.commands.record import ros_arguments
    from quad_bringup.recording.recorder import DEFAULT_TOPICS
    procs.start('recorder', ['-m', 'quad_bringup.recording.recorder_node',
                             *ros_arguments(str(bag), list(DEFAULT_TOPICS))])
    enter_offboard(observer, flavour)
    mode = OFFBOARD_MODE[flavour]
    traj = plan_waypoints(procs, observer, waypoints, speed_mps)
    settle_s = Completion.for_vehicle(load_vehicle(VEHICLE_FILE)).settle_s
    end_s = stamp_to_s(traj.header.stamp) + stamp_to_s(traj.points[-1].time_from_start) + settle_s + 1.0
    observer.wait_for(lambda: observer.odom and observer.odom[-1][0] > end_s, 'the plan end plus settle', wait_s)
    assert observer.link()[1].get('mode') == mode, f'the hand-over ended early: {observer.link()}'
    result = observer.call('land', Trigger.Request())
    assert result.success, result.message
    observer.wait_for(lambda: observer.link()[1].get('armed') == 'False', 'the vehicle to land and disarm', wait_s)
    procs.stop('recorder')   # SIGTERM: the recorder closes the bag
    metrics, report_md = report(bag, out_dir / 'report', procs.env)
    return MissionFlight(metrics, report_md, len(traj.points), bag)


def report(bag: Path, out_dir: Path, env, *options) -> tuple[dict, str]:
    """(metrics.json, report.md) of `quadflight report BAG --vehicle px4_quad.yaml --out OUT_DIR *options`."""
    done = subprocess.run([sys.executable, '-m', 'quad_bringup.cli', 'report', str(bag), '--vehicle', VEHICLE_FILE,
                           '--out', str(out_dir), *options], env=env, cwd=str(ROOT), capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    return json.loads((out_dir / 'metrics.json').read_text()), (out_dir / 'report.md').read_text()
