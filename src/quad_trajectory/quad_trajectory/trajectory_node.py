"""trajectory_node: plans a trajectory through waypoints and publishes it (docs/design.md, docs/interfaces.md).

Plans at start from `mission_file` or the flat `waypoints` parameter, and again on every
nav_msgs/Path on `waypoints`. A request that cannot be planned is refused with a logged error and an
ERROR diagnostics status; the previous trajectory stays published (latched) and in force.
"""

import dataclasses

import numpy as np
import rclpy.time
from diagnostic_msgs.msg import DiagnosticArray
from nav_msgs.msg import Path
from rclpy.clock import Clock, ClockType
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock as ClockMsg
from trajectory_msgs.msg import MultiDOFJointTrajectory
from visualization_msgs.msg import MarkerArray

from quad_common import contract, diagnostics
from quad_common.params import Param
from quad_common.paths import parameter_file
from quad_common.ros.cdr import sampled_to_trajectory, set_stamp
from quad_common.ros.node_main import run_node
from quad_common.ros.ros_params import ParameterSet
from quad_common.vehicle import load_vehicle
from quad_common.world import load_world
from quad_trajectory import messages, planner, solver, timing
from quad_trajectory.mission import DEFAULT_VEHICLE_PATH, SAMPLE_RATE_HZ, SEED_CONTROL_POINTS, load_mission

PATH_RATE_HZ = 20.0   # trajectory/path and the marker line: for viewing, not for control
DIAG_NAME = 'trajectory_node: trajectory'

SPECS = [
    Param('mission_file', '', 'mission YAML (docs/missions.md); when set, its waypoints, options, vehicle and world '
          'are used and the planning parameters below are ignored, except speed_mps', read_only=True),
    Param('fleet_vehicle', '', 'with a fleet mission_file (docs/missions.md "Fleets"): the vehicle whose plan this '
          'node publishes (its name; deconflicted as the fleet file says); its start delay is added to '
          'start_delay_s', read_only=True),
    Param('waypoints', Parameter.Type.DOUBLE_ARRAY, 'flat [x0, y0, z0, x1, y1, z1, ...] in metres (map frame); '
          'planned at start when given'),
    Param('yaw', [0.0], 'yaw (rad): one value, or one per waypoint'),
    Param('method', 'minsnap', 'minimum-derivative order', choices=tuple(solver.ORDERS)),
    Param('waypoint_constraint', 'continuity', 'continuity: smooth through waypoints; stop: at rest at each',
          choices=solver.MODES),
    Param('speed_mps', 0.0, 'average speed: total time = path length / speed; 0 = the mission\'s speed, or the '
          'seed\'s 0.5 without a mission', min=0.0, max=100.0),
    Param('time_allocation', 'sqrt', 'segment times', choices=timing.ALLOCATIONS),
    Param('control_points', False, 'insert the seed\'s control points on every leg'),
    Param('control_point_fractions', list(SEED_CONTROL_POINTS), 'where along each leg (0..1)', min=1e-3,
          max=0.999),
    Param('v_max_mps', 0.0, 'time_allocation limits: max speed; 0 = 2.0 m/s', min=0.0, max=100.0),
    Param('a_max_mps2', 0.0, 'time_allocation limits: max acceleration; 0 = half the vehicle\'s spare thrust',
          min=0.0, max=100.0),
    Param('rho', 0.0, 'time_allocation optimal: weight of total time; 0 = 2r-1', min=0.0),
    Param('margin', planner.PlanOptions.margin, 'time_allocation fastest: the fraction of each vehicle limit left '
          'unused (tilt, thrust, rotor speed, lag-inclusive tilt)', min=0.0, max=0.9),
    Param('sample_rate_hz', SAMPLE_RATE_HZ, 'rate of the points in `trajectory`', min=100.0, max=10000.0),
    Param('start_delay_s', 1.0, 'trajectory start = node clock when the plan is published + this', min=0.0,
          max=3600.0),
    Param('frame_id', 'map', 'frame of every output'),
    Param('vehicle_file', '', 'vehicle YAML for the limits (over the mission\'s vehicle); empty = the mission\'s, '
          'else config/vehicles/crazyflie.yaml', read_only=True),
    Param('world_file', '', 'world (MEAM620/rotorpy JSON or YAML) to plan collision-free in; empty = none',
          read_only=True),
    Param('robot_radius_m', 0.0, 'robot radius for the collision check', min=0.0, max=10.0),
    Param('avoid_collisions', True, 'insert points and replan until collision-free (else refuse)'),
]


class TrajectoryNode(Node):
    def __init__(self, **kwargs):
        super().__init__('trajectory_node', **kwargs)
        self.params = ParameterSet(self, SPECS, validate=self._check, on_change=self._replan_current)
        self.fleet_delay_s = 0.0   # a fleet vehicle's own start delay (after deconfliction)
        self.mission = self._load_mission() if self.params['mission_file'] else None
        if self.mission:   # vehicle_file, when given, sets the limits over the mission's vehicle
            self.vehicle = load_vehicle(self._file('vehicle_file')) if self.params['vehicle_file'] \
                else self.mission.vehicle
            self.world = self.mission.world
        else:
            self.vehicle = load_vehicle(self._file('vehicle_file') if self.params['vehicle_file'] else
                                        DEFAULT_VEHICLE_PATH)
            self.world = load_world(self._file('world_file')) if self.params['world_file'] else None
        planner.validate_options(self._options(), self.vehicle)
        c = contract
        self.traj_pub = self.create_publisher(MultiDOFJointTrajectory, c.TRAJECTORY, c.qos(c.TRAJECTORY))
        self.path_pub = self.create_publisher(Path, c.TRAJECTORY_PATH, c.qos(c.TRAJECTORY_PATH))
        self.waypoints_pub = self.create_publisher(Path, c.TRAJECTORY_WAYPOINTS, c.qos(c.TRAJECTORY_WAYPOINTS))
        self.markers_pub = self.create_publisher(MarkerArray, c.TRAJECTORY_MARKERS, c.qos(c.TRAJECTORY_MARKERS))
        self.diag_pub = self.create_publisher(DiagnosticArray, c.DIAGNOSTICS, c.qos(c.DIAGNOSTICS))
        self.create_subscription(Path, c.WAYPOINTS, self._on_waypoints, c.qos(c.WAYPOINTS))
        self.result = None          # the plan in force
        self.request = None         # (waypoints, yaw) of the plan in force
        self.last_status = diagnostics.status(DIAG_NAME, diagnostics.WARN, 'no trajectory yet')
        self.unpublished = None     # a plan made before the first /clock (use_sim_time), published once time runs
        self.first_clock_ns = None  # use_sim_time: the first /clock seen (it may be 0: a simulator's step 0)
        self.clock_wait = None
        if self._time_stopped():
            self.get_logger().info('use_sim_time: waiting for the first /clock before publishing a plan')
            self.clock_wait = self.create_subscription(ClockMsg, c.CLOCK, self._on_first_clock,
                                                       QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT))
        self.create_timer(1.0, self._publish_diagnostics, clock=Clock(clock_type=ClockType.STEADY_TIME))
        if self.mission:
            self._plan_and_publish(self.mission.waypoints, self.mission.yaw, raise_errors=True)
        elif self.params['waypoints']:
            flat = np.asarray(self.params['waypoints'], dtype=float)
            if flat.size % 3:
                raise ValueError(f'waypoints = {self.params["waypoints"]!r} must hold x, y, z per waypoint '
                                 f'(a multiple of 3 numbers, got {flat.size})')
            self._plan_and_publish(flat.reshape(-1, 3), self._yaw_param(), raise_errors=True)

    def _file(self, name) -> str:
        """The file parameter `name` found by the one lookup rule (quad_common.paths: the working directory, then
        the config directories)."""
        return parameter_file(name, self.params[name])

    def _load_mission(self):
        from quad_trajectory.fleet import is_fleet_file, load_fleet, vehicle_mission
        path, name = self._file('mission_file'), self.params['fleet_vehicle']
        if not name and is_fleet_file(path):
            raise ValueError(f'mission_file = {path!r} is a fleet mission: set fleet_vehicle to the vehicle to plan '
                             f'({", ".join(load_fleet(path).names)})')
        if not name:
            return load_mission(path)
        if not is_fleet_file(path):
            raise ValueError(f'fleet_vehicle = {name!r}: mission_file = {path!r} is not a fleet mission (no vehicles:)')
        speed = self.params['speed_mps'] or None
        mission, self.fleet_delay_s = vehicle_mission(load_fleet(path), name, speed_mps=speed)
        return mission

    # --- options ----------------------------------------------------------------------------
    def _options(self, values=None) -> planner.PlanOptions:
        v = values or self.params.values
        if self.mission:
            if v['speed_mps'] > 0:
                return dataclasses.replace(self.mission.options, speed_mps=v['speed_mps'])
            return self.mission.options
        return planner.PlanOptions(
            method=v['method'], waypoint_constraint=v['waypoint_constraint'],
            speed_mps=v['speed_mps'] or planner.PlanOptions.speed_mps,
            time_allocation=v['time_allocation'],
            control_points=tuple(v['control_point_fractions']) if v['control_points'] else (),
            v_max_mps=v['v_max_mps'] or None, a_max_mps2=v['a_max_mps2'] or None, rho=v['rho'] or None,
            margin=v['margin'],
            robot_radius_m=v['robot_radius_m'], avoid_collisions=v['avoid_collisions'])

    def _check(self, values):
        if not hasattr(self, 'vehicle'):   # start-up: the vehicle is checked once it is loaded
            return
        planner.validate_options(self._options(values), self.vehicle)

    def _yaw_param(self):
        yaw = self.params['yaw']
        return yaw[0] if len(yaw) == 1 else yaw

    # --- planning ---------------------------------------------------------------------------
    def _on_waypoints(self, msg: Path):
        try:
            positions, yaw = messages.path_to_waypoints(msg)
        except ValueError as exc:
            self._refuse(str(exc))
            return
        self._plan_and_publish(positions, yaw if yaw is not None else self.params['yaw'][0])

    def _replan_current(self, changed):
        if self.request is not None:
            self.get_logger().info(f'parameters {", ".join(changed)} changed: replanning')
            self._plan_and_publish(*self.request)

    def _plan_and_publish(self, waypoints, yaw, raise_errors=False):
        try:
            result = planner.plan(waypoints, yaw, self._options(), world=self.world, vehicle=self.vehicle)
        except ValueError as exc:
            if raise_errors:
                raise
            self._refuse(str(exc))
            return
        self.result, self.request = result, (waypoints, yaw)
        for m in result.merged:
            self.get_logger().warning(str(m))
        self._publish(result)

    def _refuse(self, reason):
        kept = 'the previous trajectory stays in force' if self.result else 'no trajectory is in force'
        self.get_logger().error(f'waypoints refused: {reason}; {kept}')
        self.last_status = diagnostics.status(DIAG_NAME, diagnostics.ERROR, f'request refused: {reason}',
                                              {'kept_previous': self.result is not None})
        self._publish_diagnostics(fault=True)

    def _time_stopped(self) -> bool:
        """use_sim_time before the first /clock: the node clock reads 0, a plan stamped now + delay would
        begin in the past once simulated time arrives (a simulator started long before)."""
        return (self.get_parameter('use_sim_time').value and self.first_clock_ns is None
                and self.get_clock().now().nanoseconds == 0)

    def _now_ns(self) -> int:
        """The node clock, never before the first /clock seen (its time source may not have taken it yet)."""
        return max(self.get_clock().now().nanoseconds, self.first_clock_ns or 0)

    def _on_first_clock(self, msg: ClockMsg):
        self.first_clock_ns = msg.clock.sec * 1_000_000_000 + msg.clock.nanosec
        self.destroy_subscription(self.clock_wait)
        self.clock_wait = None
        if self.unpublished is not None:
            result, self.unpublished = self.unpublished, None
            self._publish(result)

    def _publish(self, result: planner.PlanResult):
        if self._time_stopped():
            self.unpublished = result
            self.last_status = diagnostics.status(DIAG_NAME, diagnostics.WARN, 'planned; waiting for /clock')
            return
        frame = self.params['frame_id']
        traj = result.trajectory
        view = traj.evaluate(traj.sample_times(PATH_RATE_HZ))
        # the messages are built first (a 10,000-point plan takes a while on a busy machine), then stamped, so the
        # plan starts start_delay_s after it goes out, not after it was planned; the plan itself as bytes
        # (quad_common.ros.cdr: its Python message took ~0.1 s to build and serialize for a 1,668-point plan)
        unstamped = rclpy.time.Time().to_msg()
        plan = sampled_to_trajectory(traj.to_sampled(self.params['sample_rate_hz']), frame)
        messages_out = [
            (self.path_pub, messages.poses_to_path(view[:, :3], view[:, 3], unstamped, frame)),
            (self.waypoints_pub, messages.poses_to_path(result.waypoints, result.yaw, unstamped, frame)),
            (self.markers_pub, messages.plan_markers(result.waypoints, result.world, view[:, :3], unstamped, frame))]
        now = rclpy.time.Time(nanoseconds=self._now_ns(), clock_type=self.get_clock().clock_type)
        delay_s = self.params['start_delay_s'] + self.fleet_delay_s
        start = (now + Duration(nanoseconds=int(delay_s * 1e9))).to_msg()
        self.traj_pub.publish(bytes(set_stamp(plan, start)))
        for publisher, msg in messages_out:
            messages.stamp_all(msg, start)
            publisher.publish(msg)
        s = result.summary()
        self.get_logger().info(
            f'planned {s["segments"]} segments through {s["waypoints"]} waypoints: {s["time_planned_s"]:.2f} s, '
            f'{s["length_planned_m"]:.2f} m, max speed {s["max_speed_mps"]:.2f} m/s, start at '
            f'{start.sec}.{start.nanosec:09d}')
        self.last_status = diagnostics.status(DIAG_NAME, diagnostics.OK, 'trajectory published',
                                              {k: round(v, 4) if isinstance(v, float) else v for k, v in s.items()})
        self._publish_diagnostics()

    def _publish_diagnostics(self, fault=False):
        if self._time_stopped() and not fault:   # the periodic status waits for time to exist; a refusal does not
            return
        self.diag_pub.publish(diagnostics.array(self.get_clock().now().to_msg(), [self.last_status]))


def main(args=None):
    run_node('trajectory_node', TrajectoryNode, args=args)


if __name__ == '__main__':
    main()
