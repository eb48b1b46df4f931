"""sim_node's parameters: the table it declares (ParameterSet) and the vehicles they lay out (one, or a fleet
named by vehicle_names). No node: rclpy.parameter only types the empty array defaults."""

import math

from rclpy.parameter import Parameter

from quad_common import contract
from quad_common.params import Param
from quad_sim.simulator import PHYSICS_RATE_HZ, PHYSICS_RATE_RANGE_HZ, ROBOT_RADIUS_M, SETPOINT_TIMEOUT_S

SPECS = [
    Param('vehicle', 'config/vehicles/crazyflie.yaml', 'vehicle file (config/vehicles/*.yaml)', read_only=True),
    Param('plant', '', 'plant family member (config/plant_family.yaml) applied to the vehicle; empty: none',
          read_only=True),
    Param('initial_position', [0.0, 0.0, 1.0], 'start position, map frame (m); hovering unless on the floor',
          length=3, read_only=True),
    Param('initial_yaw', 0.0, 'start yaw (rad)', min=-math.pi, max=math.pi, read_only=True),
    Param('physics_rate_hz', PHYSICS_RATE_HZ, 'RK4 and onboard autopilot rate (Hz)', min=PHYSICS_RATE_RANGE_HZ[0],
          max=PHYSICS_RATE_RANGE_HZ[1], read_only=True),
    Param('mode', 'lockstep', 'lockstep (deterministic, as fast as the graph) or realtime (paced by rtf)',
          choices=('lockstep', 'realtime'), read_only=True),
    Param('rtf', 1.0, 'realtime mode: simulated seconds per wall second', min=0.01, max=1000.0),
    Param('lockstep_period_s', 0.01, 'lockstep: sim time per setpoint (= 1 / controller rate_hz)',
          min=1e-4, max=1.0, read_only=True),
    Param('lockstep_timeout_s', 0.5, 'lockstep: wall time to wait for a setpoint before advancing anyway',
          min=0.001, max=60.0),
    Param('odom_rate_hz', 100.0, 'realtime mode: odom and /clock rate (Hz)', min=1.0, max=1000.0,
          read_only=True),
    Param('sensor_rate_hz', 20.0, 'imu, rotor_speeds and /tf rate in sim time (Hz), at most the odom rate; '
          '0: with every odom', min=0.0, max=1000.0, read_only=True),
    Param('disturbances', 'none', 'disturbance profile name in disturbances_file', read_only=True),
    Param('disturbances_file', 'config/disturbances.yaml', 'disturbance profiles file', read_only=True),
    Param('world', '', 'world file (boxes, JSON or YAML) for collisions; empty: none', read_only=True),
    Param('robot_radius_m', ROBOT_RADIUS_M, 'collision radius around the vehicle centre (m)', min=0.0, max=5.0,
          read_only=True),
    Param('setpoint_timeout_s', SETPOINT_TIMEOUT_S, 'sim time without a setpoint before the landing failsafe',
          min=0.01, max=60.0, read_only=True),
    Param('max_tracking_error_m', 0.0, 'stop the run when farther than this from control/reference; 0: off',
          min=0.0, max=1000.0, read_only=True),
    Param('seed', 0, 'random seed of gusts and odometry noise', min=0, max=2**31 - 1, read_only=True),
    Param('vehicle_names', Parameter.Type.STRING_ARRAY, 'fleet: the vehicles, each with its topics under its name '
          '(cf1/odom, ...); empty: one vehicle, topics in the node\'s namespace', read_only=True),
    Param('vehicle_files', Parameter.Type.STRING_ARRAY, 'fleet: each vehicle\'s vehicle file; empty: `vehicle` for '
          'all', read_only=True),
    Param('initial_positions', Parameter.Type.DOUBLE_ARRAY, 'fleet: [x, y, z] of each vehicle, flat (m)',
          read_only=True),
    Param('robot_radii_m', Parameter.Type.DOUBLE_ARRAY, 'fleet: each vehicle\'s collision radius (m); empty: '
          'robot_radius_m for all', min=0.0, max=5.0, read_only=True),
    Param('duration_s', 0.0, 'lockstep: end the run (drained, exit 0) at this sim time; 0: run until stopped',
          min=0.0, max=1e6, read_only=True),
    Param('lockstep_followers', '', 'lockstep: comma-separated node names whose acknowledgements each step waits for '
          '(quad_common.ros.lockstep; e.g. recorder): nothing they record is lost', read_only=True),
    Param('mocap_rate_hz', 0.0, 'motion-capture stand-in (quad_sim.mocap) on external/pose: frames per second of sim '
          'time, at most one per step; 0: off', min=0.0, max=10000.0, read_only=True),
    Param('mocap_position_noise_m', 0.0, 'mocap: position noise, RMS per axis (m)', min=0.0, max=10.0,
          read_only=True),
    Param('mocap_attitude_noise_rad', 0.0, 'mocap: attitude noise, RMS per body axis (rad)', min=0.0, max=1.0,
          read_only=True),
    Param('mocap_latency_s', 0.0, 'mocap: sim time from the instant measured (the stamp) to publication (s)',
          min=0.0, max=10.0, read_only=True),
    Param('mocap_dropout_probability', 0.0, 'mocap: probability that a burst of lost frames starts at a frame',
          min=0.0, max=1.0, read_only=True),
    Param('mocap_dropout_burst_s', 0.0, 'mocap: a burst\'s length after its first lost frame (s); 0: one frame',
          min=0.0, max=60.0, read_only=True),
]

MOCAP_FIELDS = ('rate_hz', 'position_noise_m', 'attitude_noise_rad', 'latency_s', 'dropout_probability',
                'dropout_burst_s')  # MocapConfig's, each the parameter mocap_<field>


def fleet_layout(p) -> list[tuple]:
    """(name, vehicle file, initial position, robot radius) per vehicle: one ('' for its name) from `vehicle`,
    `initial_position` and `robot_radius_m`, or the fleet's from vehicle_names and its per-vehicle arrays (each
    checked: its length, names a ROS name component can take, no name twice). p: parameter name -> value."""
    names = p['vehicle_names']
    if not names:
        return [('', p['vehicle'], list(p['initial_position']), p['robot_radius_m'])]
    n = len(names)
    for name in names:
        if not contract.is_vehicle_name(name):
            raise ValueError(f'vehicle_names: {name!r} refused: {contract.VEHICLE_NAME_RULE}')
        if names.count(name) > 1:
            raise ValueError(f'vehicle_names: {name!r} refused: named twice')
    files = p['vehicle_files'] or [p['vehicle']] * n
    positions = p['initial_positions']
    radii = p['robot_radii_m'] or [p['robot_radius_m']] * n
    for field, values, size in (('vehicle_files', files, n), ('initial_positions', positions, 3 * n),
                                ('robot_radii_m', radii, n)):
        if len(values) != size:
            raise ValueError(f'{field} = {list(values)!r} refused: needs {size} values '
                             f'for the {n} vehicles of vehicle_names')
    return [(name, files[k], [float(x) for x in positions[3 * k:3 * k + 3]], float(radii[k]))
            for k, name in enumerate(names)]
