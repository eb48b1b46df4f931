"""The flight loop without ROS, for tuning: quad_sim's Simulator + quad_control's ControlLoop (the one
position_controller runs: hold before the plan, dt clamp, reset at the plan's start, start-step guard, lockstep
deferral) at the controller rate, tracking the mission's plan sampled as the trajectory node publishes it.

The lockstep graph's timing: at tick t_k the simulator's odometry stamped t_k arrives, the loop's tick at t_k
runs with it, and its setpoint is held for one period; minus DDS, processes and the bag. Importable with
numpy/scipy (and PyYAML) alone. The metrics come from quad_bringup.analysis.metrics, the report's own definitions, so
the numbers are defined exactly as `quadflight fly` reports them.
"""

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from quad_bringup.analysis.metrics import Completion, Flight, compute_metrics
from quad_bringup.offline.harness import Fresh, SimulatorPlant, fly
from quad_common import contract, rotations
from quad_common.paths import resolve_config
from quad_common.vehicle import load_vehicle
from quad_common.yaml_io import load_yaml
from quad_control.loop import MAX_START_STEP_M, RATE_HZ, ControlLoop
from quad_control.parameters import gains_from, profile_parameters
from quad_control.plugins import make_controller
from quad_control.position import Limits, PositionGains
from quad_sim.disturbances import load_profile, profile_from_dict
from quad_sim.simulator import PHYSICS_RATE_HZ, Simulator
from quad_trajectory.mission import DEFAULT_VEHICLE_PATH, SAMPLE_RATE_HZ, load_mission, plan_mission

DISTURBANCES_FILE = resolve_config('config/disturbances.yaml')  # installed share, else the checkout


@dataclass
class LoopOptions:
    controller: str = 'pd'
    gains: PositionGains | None = None          # None: the seed's
    speed_mps: float | None = None              # None: the mission's
    plan_overrides: dict | None = None          # PlanOptions fields (e.g. time_allocation='limits')
    disturbances: str | dict = 'none'           # a profile of config/disturbances.yaml, or one as a mapping
    plant: str | dict | None = None             # a plant family member (name or overrides) for the simulator only
    vehicle_path: str | None = None             # None: the mission's vehicle file
    bag_dir: Path | None = None                 # also write odom and cmd/attitude_thrust as a rosbag2 bag here
    odom_latency_s: float = 0.0                 # the controller sees the state this much old (telemetry delay)
    seed: int = 0                               # the simulator's (gusts, odometry noise)
    rate_hz: float = RATE_HZ
    physics_rate_hz: float = PHYSICS_RATE_HZ
    time_limit_factor: float = 3.0
    rule: Completion = Completion()
    start_delay_s: float = 0.0                  # the plan starts this long after t = 0 (held before)
    max_start_step_m: float = MAX_START_STEP_M


@dataclass
class OfflineRun:
    """One offline flight: the report's metrics and what each tick saw and commanded."""
    metrics: dict
    t_s: np.ndarray = field(default_factory=lambda: np.zeros(0))              # tick times
    setpoints: list = field(default_factory=list)                             # AttitudeSetpoint per tick
    references: list = field(default_factory=list)                            # Reference per tick
    loop: ControlLoop | None = None


class FlightBag:
    """odom (nav_msgs/Odometry, body-frame twist) and cmd/attitude_thrust (sensor_msgs/Imu as a setpoint) as
    the graph records them, written with rosbags (quad_bringup.recording.recorder.BagRecorder): a real rosbag2 bag."""

    def __init__(self, path):
        from quad_bringup.recording.recorder import DEFAULT_TOPICS, BagRecorder, typestore
        self.ts = typestore()
        self.writer = BagRecorder(path)
        for topic in (contract.ODOM, contract.SETPOINT):
            self.writer.add_topic(topic, DEFAULT_TOPICS[topic])
        self._topics = DEFAULT_TOPICS

    def write_trajectory(self, start_s, trajectory):
        """The plan as trajectory_node latches it (quad_common.conversions.sampled_to_msg's fields): `replay`
        flies it again, `report` scores against it."""
        T = self.ts.types
        vec, twist = T['geometry_msgs/msg/Vector3'], T['geometry_msgs/msg/Twist']
        points = []
        for t, p, v, a in zip(trajectory.times_s - trajectory.times_s[0], trajectory.position, trajectory.velocity,
                              trajectory.acceleration):
            ns = int(round(t * 1e9))
            points.append(T['trajectory_msgs/msg/MultiDOFJointTrajectoryPoint'](
                transforms=[T['geometry_msgs/msg/Transform'](
                    translation=vec(*map(float, p[:3])),
                    rotation=T['geometry_msgs/msg/Quaternion'](*map(float, rotations.from_yaw(float(p[3])))))],
                velocities=[twist(linear=vec(*map(float, v[:3])), angular=vec(0.0, 0.0, float(v[3])))],
                accelerations=[twist(linear=vec(*map(float, a[:3])), angular=vec(0.0, 0.0, float(a[3])))],
                time_from_start=T['builtin_interfaces/msg/Duration'](sec=ns // 10**9, nanosec=ns % 10**9)))
        msg = T['trajectory_msgs/msg/MultiDOFJointTrajectory'](header=self._header(start_s, 'map'),
                                                              joint_names=['base_link'], points=points)
        self.writer.add_topic('trajectory', self._topics['trajectory'])
        self.writer.write('trajectory', int(round(start_s * 1e9)),
                          self.ts.serialize_cdr(msg, 'trajectory_msgs/msg/MultiDOFJointTrajectory'))

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
        v_body = rotations.rotate_back(q.tolist(), state.velocity.tolist())   # conversions.body_velocity (no ROS)
        odom = T['nav_msgs/msg/Odometry'](
            header=self._header(t_s, contract.WORLD_FRAME), child_frame_id=contract.BODY_FRAME,
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
            rates_cov[0] = contract.UNSET_COVARIANCE
        imu = T['sensor_msgs/msg/Imu'](
            header=self._header(t_s, contract.BODY_FRAME), orientation=quat(*map(float, setpoint.quaternion)),
            orientation_covariance=np.zeros(9), angular_velocity=vec(*map(float, rates)),
            angular_velocity_covariance=rates_cov,
            linear_acceleration=vec(0.0, 0.0, float(setpoint.specific_force_mps2)),
            linear_acceleration_covariance=np.zeros(9))
        ns = int(round(t_s * 1e9))
        self.writer.write(contract.ODOM, ns, self.ts.serialize_cdr(odom, contract.TOPICS[contract.ODOM].msgtype))
        self.writer.write(contract.SETPOINT, ns, self.ts.serialize_cdr(imu, contract.TOPICS[contract.SETPOINT].msgtype))

    def close(self):
        self.writer.close()


def load_control_profile(path) -> tuple[str, PositionGains]:
    """(controller, gains) of a position_controller params file (config/control*.yaml) over the seed's."""
    return control_profile(load_yaml(resolve_config(path)) or {})


def control_profile(content: dict) -> tuple[str, PositionGains]:
    """(controller, gains) of a params file's content over the seed's."""
    values = profile_parameters(content)
    return values.get('controller', 'pd'), gains_from(values)


def fly_offline(mission_path, options: LoopOptions | None = None) -> dict:
    """Plans and flies one mission; returns the report's metrics (plus 'stopped' when the sim gave up)."""
    return run_offline(mission_path, options).metrics


def plan_offline(mission_path, options: LoopOptions | None = None):
    """(mission, plan, trajectory sampled as trajectory_node publishes it)."""
    options = options or LoopOptions()
    mission = load_mission(mission_path)
    plan = plan_mission(mission, speed_mps=options.speed_mps, **(options.plan_overrides or {}))
    return mission, plan, plan.trajectory.to_sampled(SAMPLE_RATE_HZ)


def controller_vehicle(mission, options: LoopOptions):
    """The vehicle the controller is configured with (the plant family acts on the simulator only)."""
    return load_vehicle(resolve_config(options.vehicle_path)) if options.vehicle_path else mission.vehicle


def make_simulator(mission, trajectory, options: LoopOptions) -> Simulator:
    """The simulator as fly starts it: at the mission's initial position, facing the plan's first yaw, flying
    the plant family member if one is named."""
    profile = (profile_from_dict({k: v for k, v in options.disturbances.items() if k != 'name'},
                                 options.disturbances.get('name', 'inline'))
               if isinstance(options.disturbances, dict) else load_profile(DISTURBANCES_FILE, options.disturbances))
    vehicle = controller_vehicle(mission, options)
    plant_vehicle = load_vehicle(resolve_config(options.vehicle_path) if options.vehicle_path else
                                 mission.vehicle_path or DEFAULT_VEHICLE_PATH, plant=options.plant) \
        if options.plant else vehicle
    return Simulator(plant_vehicle, options.physics_rate_hz, initial_position=mission.initial_position,
                     initial_yaw=float(trajectory.position[0, 3]), disturbances=profile, world=mission.world,
                     robot_radius_m=mission.options.robot_radius_m, seed=options.seed)


def run_offline(mission_path, options: LoopOptions | None = None) -> OfflineRun:
    """fly_offline, keeping the per-tick setpoints and references."""
    options = options or LoopOptions()
    mission, plan, trajectory = plan_offline(mission_path, options)
    sim = make_simulator(mission, trajectory, options)
    vehicle = controller_vehicle(mission, options)
    controller = make_controller(options.controller, options.gains or PositionGains(), vehicle, Limits.of(vehicle),
                                 options.rate_hz)
    loop = ControlLoop(controller, options.rate_hz, lockstep=True, max_start_step_m=options.max_start_step_m)
    period_ns = round(1e9 / options.rate_hz)
    loop.set_trajectory(round(options.start_delay_s * 1e9), trajectory)
    arrival_s = options.rule.plan_arrival_s(trajectory)
    end_s = options.time_limit_factor * trajectory.duration_s + 10.0 + options.start_delay_s

    def done(t_ns, truth):
        elapsed_s = t_ns * 1e-9 - options.start_delay_s
        return elapsed_s >= arrival_s and options.rule.done(elapsed_s, truth.position, truth.velocity, trajectory,
                                                            arrival_s)

    bag = FlightBag(options.bag_dir) if options.bag_dir else None

    def record(t_ns, seen, tick):
        if bag and tick is not None:
            bag.write(t_ns * 1e-9, seen[1], tick.setpoint)

    try:
        flown = fly(loop, SimulatorPlant(sim), Fresh(round(options.odom_latency_s / (period_ns * 1e-9))),
                    int(end_s * options.rate_hz) + 1, done=done, on_tick=record)
    finally:
        if bag:
            bag.close()
    ticks = [t for t in flown.ticks if t is not None]
    truth = flown.truth
    collision = next((e.time_s for e in sim.events if e.kind == 'collision'), None)
    flight = Flight(odom_t=flown.t_s_array(), position=np.array([s.position for s in truth]),
                    velocity=np.array([s.velocity for s in truth]),
                    euler=rotations.to_euler(np.array([s.quaternion for s in truth])),
                    traj_start_s=options.start_delay_s,
                    trajectory=trajectory,
                    waypoints=plan.waypoints, collision_time_s=collision)
    metrics = compute_metrics(flight, options.rule)
    metrics['max_yaw_rate_radps'] = max((abs(float(s.body_rates[2])) for s in truth), default=0.0)
    metrics['saturated_s'] = sim.saturated_steps * sim.step_s  # physics steps the mixer reduced an axis in
    metrics['saturated_fraction'] = flown.saturated_ticks() / max(len(truth) - 1, 1)  # thrust or tilt clamped
    if flown.stopped:
        metrics['stopped'] = flown.stopped
    return OfflineRun(metrics, np.array([t.t_ns * 1e-9 for t in ticks]), [t.setpoint for t in ticks],
                      [t.reference for t in ticks], loop)
