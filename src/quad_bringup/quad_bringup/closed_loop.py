"""The flight loop without ROS, for tuning: quad_sim's Simulator + a quad_control PositionController at the
controller rate, tracking the mission's plan sampled as the trajectory node publishes it.

Same pieces and the same timing as the lockstep graph (at tick t_k the controller sees the odometry of t_k, its
setpoint is held for one period), minus DDS, processes and the bag; the metrics come from the report's own
`compute_metrics` on the simulated arrays, so the numbers are defined exactly as `quadflight fly` reports them.
"""

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from quad_bringup.report import Completion, Flight, compute_metrics
from quad_common import rotations
from quad_common.paths import resolve_config
from quad_common.types import Reference
from quad_common.vehicle import load_vehicle
from quad_common.yaml_io import load_yaml
from quad_control.position import Limits, PositionController, PositionGains, gains_from_parameters
from quad_sim.disturbances import load_profile
from quad_sim.simulator import SimulationStopped, Simulator
from quad_trajectory.mission import load_mission, plan_mission

REPO_ROOT = Path(__file__).resolve().parents[3]
DISTURBANCES_FILE = REPO_ROOT / 'config' / 'disturbances.yaml'
SAMPLE_RATE_HZ = 100.0   # config/trajectory.yaml sample_rate_hz


@dataclass
class LoopOptions:
    controller: str = 'pd'
    gains: PositionGains | None = None          # None: the seed's
    speed_mps: float | None = None              # None: the mission's
    plan_overrides: dict | None = None          # PlanOptions fields (e.g. time_allocation='limits')
    disturbances: str = 'none'
    plant: str | dict | None = None             # a plant family member (name or overrides) for the simulator only
    vehicle_path: str | None = None             # None: the mission's vehicle file
    bag_dir: Path | None = None                 # also write odom and cmd/attitude_thrust as a rosbag2 bag here
    odom_latency_s: float = 0.0                 # the controller sees the state this much old (telemetry delay)
    rate_hz: float = 100.0
    physics_rate_hz: float = 1000.0
    time_limit_factor: float = 3.0
    rule: Completion = Completion()


class _Delay:
    """The state as seen latency_s (a whole number of periods) late; the first one until then."""

    def __init__(self, latency_s, period_s):
        self.steps = int(round(latency_s / period_s))
        self.queue = []

    def __call__(self, state):
        self.queue.append(state)
        if len(self.queue) > self.steps + 1:
            self.queue.pop(0)
        return self.queue[0]


class FlightBag:
    """odom (nav_msgs/Odometry, body-frame twist) and cmd/attitude_thrust (sensor_msgs/Imu as a setpoint) as
    the graph records them, written with rosbags (quad_bringup.recorder.BagRecorder): a real rosbag2 bag."""

    def __init__(self, path):
        from quad_bringup.recorder import DEFAULT_TOPICS, BagRecorder, typestore
        self.ts = typestore()
        self.writer = BagRecorder(path)
        for topic in ('odom', 'cmd/attitude_thrust'):
            self.writer.add_topic(topic, DEFAULT_TOPICS[topic])

    def _header(self, t_s, frame):
        T = self.ts.types
        ns = int(round(t_s * 1e9))
        return T['std_msgs/msg/Header'](stamp=T['builtin_interfaces/msg/Time'](sec=ns // 10**9, nanosec=ns % 10**9),
                                        frame_id=frame)

    def write(self, t_s, state, setpoint):
        T = self.ts.types
        vec = T['geometry_msgs/msg/Vector3']
        quat = T['geometry_msgs/msg/Quaternion']
        q = state.quaternion
        v_body = rotations.to_matrix(q).T @ state.velocity
        odom = T['nav_msgs/msg/Odometry'](
            header=self._header(t_s, 'map'), child_frame_id='base_link',
            pose=T['geometry_msgs/msg/PoseWithCovariance'](
                pose=T['geometry_msgs/msg/Pose'](position=T['geometry_msgs/msg/Point'](*map(float, state.position)),
                                                 orientation=quat(*map(float, q))), covariance=np.zeros(36)),
            twist=T['geometry_msgs/msg/TwistWithCovariance'](
                twist=T['geometry_msgs/msg/Twist'](linear=vec(*map(float, v_body)),
                                                   angular=vec(*map(float, state.body_rates))),
                covariance=np.zeros(36)))
        rates = setpoint.body_rates if setpoint.body_rates is not None else np.zeros(3)
        rates_cov = np.zeros(9)
        if setpoint.body_rates is None:
            rates_cov[0] = -1.0
        imu = T['sensor_msgs/msg/Imu'](
            header=self._header(t_s, 'base_link'), orientation=quat(*map(float, setpoint.quaternion)),
            orientation_covariance=np.zeros(9), angular_velocity=vec(*map(float, rates)),
            angular_velocity_covariance=rates_cov,
            linear_acceleration=vec(0.0, 0.0, float(setpoint.specific_force_mps2)),
            linear_acceleration_covariance=np.zeros(9))
        ns = int(round(t_s * 1e9))
        self.writer.write('odom', ns, self.ts.serialize_cdr(odom, 'nav_msgs/msg/Odometry'))
        self.writer.write('cmd/attitude_thrust', ns, self.ts.serialize_cdr(imu, 'sensor_msgs/msg/Imu'))

    def close(self):
        self.writer.close()


def hold_offline(vehicle_path, controller: str, gains: PositionGains, plant=None, start_offset_m=(0.5, 0.0, 0.0),
                 duration_s: float = 20.0, odom_latency_s: float = 0.0, rate_hz: float = 100.0) -> dict:
    """Hold a point from a start offset: the position loop against the vehicle's (plant's) attitude response
    and a telemetry delay. Returns the final offset (mean over the last quarter, m), the largest tilt over the
    last quarter (deg: a sustained oscillation keeps it large) and over the whole hold."""
    nominal = load_vehicle(vehicle_path)
    vehicle = load_vehicle(vehicle_path, plant=plant) if plant else nominal
    target = np.array([0.0, 0.0, 2.0])
    sim = Simulator(vehicle, initial_position=target + np.asarray(start_offset_m, dtype=float))
    control = PositionController(controller, gains, nominal, Limits.of(nominal))
    ref = Reference(position=target, velocity=np.zeros(3), acceleration=np.zeros(3), jerk=np.zeros(3), yaw=0.0,
                    yaw_rate=0.0)
    delayed, period_s = _Delay(odom_latency_s, 1.0 / rate_hz), 1.0 / rate_hz
    positions, tilts = [], []
    for k in range(int(round(duration_s * rate_hz))):
        setpoint, _ = control.update(delayed(sim.odometry_state()), ref, period_s if k else 0.0)
        sim.set_setpoint(setpoint)
        sim.advance(period_s)
        positions.append(sim.state.position)
        roll, pitch, _ = rotations.to_euler(sim.state.quaternion)
        tilts.append(np.degrees(np.hypot(roll, pitch)))
    last = len(positions) * 3 // 4
    return {'offset_m': float(np.linalg.norm(np.mean(positions[last:], axis=0) - target)),
            'late_tilt_deg': float(np.max(tilts[last:])), 'peak_tilt_deg': float(np.max(tilts))}


def load_control_profile(path) -> tuple[str, PositionGains]:
    """(controller, gains) of a position_controller params file (config/control*.yaml) over the seed's."""
    values = (load_yaml(resolve_config(path)) or {}).get('position_controller', {}).get('ros__parameters', {})
    return values.get('controller', 'pd'), gains_from_parameters(values)


def fly_offline(mission_path, options: LoopOptions | None = None) -> dict:
    """Plans and flies one mission; returns the report's metrics (plus 'stopped' when the sim gave up)."""
    options = options or LoopOptions()
    mission = load_mission(mission_path)
    plan = plan_mission(mission, speed_mps=options.speed_mps, **(options.plan_overrides or {}))
    trajectory = plan.trajectory.to_sampled(SAMPLE_RATE_HZ)
    profile = load_profile(DISTURBANCES_FILE, options.disturbances)
    vehicle = load_vehicle(options.vehicle_path) if options.vehicle_path else mission.vehicle
    plant_vehicle = load_vehicle(options.vehicle_path or mission.vehicle_path, plant=options.plant) \
        if options.plant else vehicle
    sim = Simulator(plant_vehicle, options.physics_rate_hz, initial_position=mission.initial_position,
                    initial_yaw=float(trajectory.position[0, 3]), disturbances=profile, world=mission.world,
                    robot_radius_m=mission.options.robot_radius_m)
    controller = PositionController(options.controller, options.gains or PositionGains(), vehicle,
                                    Limits.of(vehicle))
    period_s = 1.0 / options.rate_hz
    arrival_s = options.rule.plan_arrival_s(trajectory)
    end_s = options.time_limit_factor * trajectory.duration_s + 10.0
    times, positions, velocities, eulers = [], [], [], []
    max_yaw_rate = 0.0
    stopped = None
    bag = FlightBag(options.bag_dir) if options.bag_dir else None
    delayed = _Delay(options.odom_latency_s, period_s)
    for k in range(int(end_s * options.rate_hz) + 1):
        t_s = k * period_s
        truth = sim.state
        times.append(t_s)
        positions.append(truth.position)
        velocities.append(truth.velocity)
        eulers.append(rotations.to_euler(truth.quaternion))
        max_yaw_rate = max(max_yaw_rate, abs(float(truth.body_rates[2])))
        if options.rule.done(t_s, truth.position, truth.velocity, trajectory, arrival_s):
            break
        ref = trajectory.reference(min(t_s, trajectory.duration_s))
        seen = delayed(sim.odometry_state())
        setpoint, _ = controller.update(seen, ref, period_s if k else 0.0)
        sim.set_setpoint(setpoint)
        if bag:
            bag.write(t_s, seen, setpoint)
        try:
            sim.advance(period_s)
        except SimulationStopped as exc:
            stopped = str(exc)
            break
    if bag:
        bag.close()
    collision = next((e.time_s for e in sim.events if e.kind == 'collision'), None)
    flight = Flight(odom_t=np.array(times), position=np.array(positions), velocity=np.array(velocities),
                    euler=np.array(eulers), traj_start_s=0.0, trajectory=trajectory, waypoints=plan.waypoints,
                    collision_time_s=collision)
    metrics = compute_metrics(flight, options.rule)
    metrics['max_yaw_rate_radps'] = max_yaw_rate
    metrics['saturated_s'] = sim.saturated_steps * sim.step_s  # physics steps the mixer reduced an axis in
    if stopped:
        metrics['stopped'] = stopped
    return metrics
