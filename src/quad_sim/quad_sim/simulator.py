"""The simulated vehicle: rigid body + rotors + onboard autopilot + failsafe + floor + world + disturbances.

Time is kept in integer nanoseconds; `advance` runs a whole number of fixed physics steps. Every physics
step the onboard autopilot turns the held setpoint into body moments with the vehicle's attitude loop
(`onboard_moments`: the seed's equation 6, quad_sim.onboard_attitude.moments, by default; an autopilot's
SO(3) cascade or a lagged attitude target, quad_common.vehicle.AttitudeLoop) and a collective thrust
(specific force * nominal mass * (1 + thrust_error)), the mixer turns them into rotor speed commands
(reporting saturation), and RK4 integrates the plant (mass_kg (1 + mass_error)) over the step.

Speed: the step is compiled (quad_common.compiled). `quiet_steps` runs whole runs of steps in which
nothing happens that needs bookkeeping (no saturation, floor, limit, collision suspicion, failsafe,
gusts); it leaves the first step that does to `_physics_step`, which runs the same kernels one step at a
time with the event logic around them. The result is the same either way.

Failsafe (like PX4's / ArduPilot's setpoint-loss landing, which hold position horizontally while they descend):
when no setpoint arrived for setpoint_timeout_s, the autopilot brakes back to p_hold, where the vehicle was when
the last setpoint arrived, and descends at failsafe_descent_mps, keeping the current yaw:
    a_xy = k_p (p_hold - p)_xy - k_d v_xy,  |a_xy| <= g tan(FAILSAFE_MAX_TILT),
    a_z  = k_v (-descent - v_z),  specific force g + a_z clipped to [0.5 g, 1.5 g],
thrust along (a_xy, g + a_z); it disarms (rotors to their minimum speed) once it rests on the floor. A new
setpoint ends it. From a 2 m/s flight it comes down within a few cm of p_hold (test_simulator).

Floor at z = floor_z_m (the world's lower bound, else 0): the vehicle never goes below it; it rests
(zero velocity and rates, level, yaw kept) while the thrust's vertical part cannot lift its weight.
"""

import math
import os
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from quad_common import rotations
from quad_common.compiled import float_array, njit, one_compiler
from quad_common.types import GRAVITY_MPS2, AttitudeSetpoint, State
from quad_common.vehicle import Vehicle
from quad_common.world import World
from quad_sim.disturbances import DisturbanceProfile, Gusts
from quad_sim.mixer import Mixer, flag_names, rotor_commands
from quad_sim.onboard_attitude import desired_rates, moments
from quad_sim.rigid_body import NO_FORCE, STATE_SIZE, RigidBody, rk4_step

NON_FINITE, SPEED_LIMIT, BODY_RATE_LIMIT, FAR_FROM_REFERENCE = (
    'non_finite_state', 'speed_limit', 'body_rate_limit', 'far_from_reference')
PHYSICS_RATE_HZ = 1000.0      # RK4 and onboard loop steps per second: sim_node's and the offline loop's default
PHYSICS_RATE_RANGE_HZ = (100.0, 100000.0)   # what any simulator (sim_node, the emulator, the harness) accepts
ROBOT_RADIUS_M = 0.1          # collision radius around the vehicle centre: sim_node's default
SETPOINT_TIMEOUT_S = 0.5      # sim time without a setpoint before the landing failsafe: sim_node's default
FAILSAFE_VELOCITY_GAIN = 2.0  # 1/s, vertical speed loop of the landing failsafe
FAILSAFE_POSITION_GAIN = 4.0  # 1/s^2, horizontal hold: omega_n = 2 rad/s, critically damped with
FAILSAFE_DAMPING_GAIN = 4.0   # 1/s
FAILSAFE_MAX_TILT_RAD = math.radians(30.0)
SATURATION_GAP_S = 0.1        # a saturation event is reported when saturation starts after this long without
# the autopilot's input as the kernels take it: quaternion (4), collective thrust (N), desired body rates (3)
SP_QUATERNION, SP_THRUST, SP_RATES, SP_SIZE = slice(0, 4), 4, slice(5, 8), 8
# the onboard attitude loop's parameters (AttitudeLoop): type, kp (3), kd (3), lag time constant, roll/pitch rate
# feed-forward on (0/1), thrust scale; its state: the lag's attitude target (4) and target rates (3)
ATT_TYPE, ATT_KP, ATT_KD, ATT_TAU, ATT_FF_PQ, ATT_THRUST_SCALE, ATT_SIZE = 0, 1, 4, 7, 8, 9, 10
LOOP_EQ6, LOOP_SO3_PD, LOOP_LAG = 0.0, 1.0, 2.0
LOOP_CODES = {'eq6': LOOP_EQ6, 'so3_pd': LOOP_SO3_PD, 'lag': LOOP_LAG}
# quiet_steps' limits: floor z, squared max speed, squared max body rate
LIMIT_FLOOR, LIMIT_SPEED2, LIMIT_RATE2 = 0, 1, 2


class SimulationStopped(RuntimeError):
    """A validity check failed: the run cannot go on meaningfully (reason is one of the constants above)."""

    def __init__(self, reason: str, time_s: float, position, detail: str = ''):
        self.reason, self.time_s, self.position = reason, time_s, np.asarray(position, dtype=float)
        super().__init__(f'simulation stopped at t = {time_s:.3f} s, position {np.round(self.position, 3).tolist()}: '
                         f'{reason}{" (" + detail + ")" if detail else ""}')


@dataclass
class Event:
    """Something a run report should show: kind in collision, failsafe, failsafe_cleared, disarmed,
    saturation, touchdown, takeoff, stopped."""

    kind: str
    time_s: float
    position: np.ndarray
    detail: dict = field(default_factory=dict)


class Simulator:
    def __init__(self, vehicle: Vehicle, physics_rate_hz: float = PHYSICS_RATE_HZ, initial_position=(0.0, 0.0, 0.0),
                 initial_yaw: float = 0.0, disturbances: DisturbanceProfile | None = None,
                 world: World | None = None, robot_radius_m: float = ROBOT_RADIUS_M, seed: int = 0,
                 setpoint_timeout_s: float = SETPOINT_TIMEOUT_S, floor_z_m: float | None = None,
                 max_speed_mps: float = 50.0, max_body_rate_radps: float = 100.0, failsafe_descent_mps: float = 0.5):
        low, high = PHYSICS_RATE_RANGE_HZ
        self._check(math.isfinite(physics_rate_hz) and low <= physics_rate_hz <= high, 'physics_rate_hz',
                    physics_rate_hz, f'must be a number in [{low:g}, {high:g}]')
        self.step_ns = int(round(1e9 / physics_rate_hz))
        for name, value in (('setpoint_timeout_s', setpoint_timeout_s), ('robot_radius_m', robot_radius_m),
                            ('max_speed_mps', max_speed_mps), ('max_body_rate_radps', max_body_rate_radps),
                            ('failsafe_descent_mps', failsafe_descent_mps)):
            self._check(math.isfinite(value) and value >= 0, name, value, 'must be a finite number >= 0')
        self.vehicle = vehicle
        self.physics_rate_hz = physics_rate_hz
        self.step_s = self.step_ns * 1e-9
        self.profile = disturbances or DisturbanceProfile()
        self.world = world
        self.robot_radius_m = float(robot_radius_m)
        self.floor_z_m = float(floor_z_m if floor_z_m is not None else (world.bounds[4] if world else 0.0))
        self.initial_position = np.asarray(initial_position, dtype=float)
        self._check(self.initial_position.shape == (3,) and np.all(np.isfinite(self.initial_position)),
                    'initial_position', initial_position, 'must be 3 finite numbers')
        self._check(self.initial_position[2] >= self.floor_z_m, 'initial_position', initial_position,
                    f'is below the floor z = {self.floor_z_m}')
        self._check(math.isfinite(initial_yaw), 'initial_yaw', initial_yaw, 'must be finite')
        self.initial_yaw = float(initial_yaw)
        self.seed = int(seed)
        self.setpoint_timeout_ns = int(round(setpoint_timeout_s * 1e9))
        self.max_speed_mps, self.max_body_rate_radps = max_speed_mps, max_body_rate_radps
        self.failsafe_descent_mps = failsafe_descent_mps
        self.body = RigidBody(vehicle, self.profile.aerodynamics(vehicle))
        self.mixer = Mixer(vehicle)
        self._inertia = float_array(vehicle.inertia_matrix)
        self._att = attitude_parameters(vehicle)
        self._att_state = np.zeros(7)
        self._limits = float_array([self.floor_z_m, max_speed_mps ** 2, max_body_rate_radps ** 2])
        self._collision_world = None
        self._inflated_blocks = np.zeros((0, 6))  # lo x, y, z, hi x, y, z of each block grown by the radius
        self._safe_bounds = float_array([-np.inf] * 3 + [np.inf] * 3)
        if world is not None:  # the floor is ground contact, not a collision: drop the bounds' lower face
            bounds = world.bounds.copy()
            bounds[4] -= 1e6
            self._collision_world = World(bounds, world.blocks, name=world.name)
            r = self.robot_radius_m
            self._inflated_blocks = float_array([tuple(b[0::2] - r) + tuple(b[1::2] + r) for b in world.blocks]
                                                ).reshape(-1, 6)
            self._safe_bounds = float_array(tuple(world.bounds[0::2] + r) + tuple(world.bounds[1::2] - r))
        self._thrusts = np.empty(4)
        self.reset()

    @staticmethod
    def _check(ok, name, value, rule):
        if not ok:
            raise ValueError(f'{name} = {value!r} {rule}')

    # --- state --------------------------------------------------------------------------------------------

    def reset(self):
        """Back to the initial state: hovering at initial_position (resting, if that is on the floor)."""
        q0 = rotations.from_yaw(self.initial_yaw)
        self.landed = bool(self.initial_position[2] <= self.floor_z_m)
        hover = math.sqrt(self.plant_weight_n / (4 * self.vehicle.k_eta))
        w0 = self.vehicle.rotor_speed_min_radps if self.landed else hover
        self._x = float_array([*self.initial_position, 0.0, 0.0, 0.0, *q0, 0.0, 0.0, 0.0, w0, w0, w0, w0])
        assert len(self._x) == STATE_SIZE
        self._w_cmd = np.full(4, w0)
        self._att_state[:] = [*q0, 0.0, 0.0, 0.0]
        self.time_ns = 0
        self._set_setpoint_vector(AttitudeSetpoint(quaternion=q0, specific_force_mps2=GRAVITY_MPS2))
        self._setpoint_time_ns = 0
        self._hold_position = self._x[0:3].copy()  # where the vehicle was at the last setpoint (failsafe)
        self.failsafe_active = False
        self.armed = True
        self._failsafe_quaternion = q0
        self.saturation = ()
        self.saturated_steps = 0
        self._last_saturated_ns = None
        self.colliding = False
        self.collision_count = 0
        self.events: list[Event] = []
        self.stopped: SimulationStopped | None = None
        self._rng_gusts = np.random.default_rng([self.seed, 0])
        self._rng_noise = np.random.default_rng([self.seed, 1])
        self._gusts = Gusts(self.profile, self.step_s, self._rng_gusts) if self.profile.has_gusts else None
        self._wind = float_array(self.profile.wind_mps).copy()
        self._history = deque()

    @property
    def time_s(self) -> float:
        return self.time_ns * 1e-9

    @property
    def plant_weight_n(self) -> float:
        """The simulated vehicle's true weight (mass_kg (1 + mass_error) g)."""
        return self.vehicle.plant_mass_kg * GRAVITY_MPS2

    @property
    def state(self) -> State:
        x = self._x
        return State(position=np.array(x[0:3]), velocity=np.array(x[3:6]), quaternion=np.array(x[6:10]),
                     body_rates=np.array(x[10:13]))

    @property
    def position_m(self) -> np.ndarray:
        """The true position (a view: copy it to keep it)."""
        return self._x[0:3]

    @property
    def rotor_speeds_radps(self) -> np.ndarray:
        return np.array(self._x[13:17])

    @property
    def wind_mps(self) -> np.ndarray:
        return np.array(self._wind)

    @property
    def specific_force_body_mps2(self) -> np.ndarray:
        """What an ideal accelerometer reads: R^T (a + g e3); at rest on the floor R^T g e3."""
        x = self._x
        R = rotations.to_matrix(x[6:10])
        if self.landed:
            accel = np.zeros(3)
        else:
            accel = np.array(self.body.derivative(x, self._w_cmd, wind_world=self._wind)[3:6])
        return R.T @ (accel + np.array([0.0, 0.0, GRAVITY_MPS2]))

    @property
    def collided(self) -> bool:
        return self.collision_count > 0

    def odometry_state(self) -> State:
        """The state as a motion-capture system reports it: profile latency (state at the newest advance()
        end at least odom_latency_s old) and Gaussian noise (seeded). The truth is `state`."""
        latency_ns = int(round(self.profile.odom_latency_s * 1e9))
        state = self.state
        if latency_ns > 0 and self._history:
            for t_ns, past in reversed(self._history):
                if t_ns <= self.time_ns - latency_ns:
                    state = past
                    break
            else:
                state = self._history[0][1]
        if not self.profile.has_odom_noise:
            return state
        n, rng = self.profile.odom_noise, self._rng_noise
        tilt = rng.standard_normal(3) * n['attitude_std_rad']
        dq = np.append(0.5 * tilt, 1.0)
        return State(position=state.position + rng.standard_normal(3) * n['position_std_m'],
                     velocity=state.velocity + rng.standard_normal(3) * n['velocity_std_mps'],
                     quaternion=rotations.normalize(rotations.multiply(state.quaternion, dq)),
                     body_rates=state.body_rates + rng.standard_normal(3) * n['body_rates_std_radps'])

    # --- inputs -------------------------------------------------------------------------------------------

    def set_setpoint(self, setpoint: AttitudeSetpoint):
        """The autopilot's input, received now (sim time); held until the next one."""
        if not setpoint.is_finite():
            raise ValueError(f'setpoint must be finite, got {setpoint}')
        self._set_setpoint_vector(setpoint)
        self._setpoint_time_ns = self.time_ns
        self._hold_position[:] = self._x[0:3]
        if self.failsafe_active:
            self.failsafe_active = False
            self.armed = True
            self._event('failsafe_cleared')

    def _set_setpoint_vector(self, setpoint: AttitudeSetpoint):
        self._setpoint = setpoint
        self._setpoint_vector = self._autopilot_input(setpoint.quaternion, setpoint.specific_force_mps2,
                                                      desired_rates(setpoint, use_feedforward_rates=True))

    def _autopilot_input(self, quaternion, specific_force_mps2, rates_des=(0.0, 0.0, 0.0)) -> np.ndarray:
        sp = np.empty(SP_SIZE)
        sp[SP_QUATERNION], sp[SP_RATES] = quaternion, rates_des
        sp[SP_THRUST] = max(specific_force_mps2, 0.0) * self.vehicle.mass_kg
        return sp

    def check_tracking(self, reference_position, max_error_m: float):
        """Stops the run when the vehicle is farther than max_error_m from the reference position."""
        error = float(np.linalg.norm(np.asarray(reference_position, dtype=float) - self._x[0:3]))
        if not error <= max_error_m:
            self._stop(FAR_FROM_REFERENCE, f'{error:.2f} m from the reference, limit {max_error_m} m')

    # --- time ---------------------------------------------------------------------------------------------

    def steps_in(self, duration_s: float) -> int:
        """Number of physics steps in duration_s; refuses a duration that is not a whole number of steps."""
        duration_ns = int(round(duration_s * 1e9))
        steps, rest = divmod(duration_ns, self.step_ns)
        if rest or duration_ns < 0:
            raise ValueError(f'duration {duration_s!r} s is not a whole number of physics steps '
                             f'of {self.step_ns} ns ({self.physics_rate_hz} Hz)')
        return steps

    def advance(self, duration_s: float):
        """Simulates duration_s (a whole number of physics steps). Raises SimulationStopped."""
        self.advance_steps(self.steps_in(duration_s))

    def advance_steps(self, steps: int):
        if self.stopped is not None:
            raise self.stopped
        while steps > 0:
            if not self.failsafe_active and self.armed and not self.landed and self._gusts is None:
                done = quiet_steps(self._x, self._w_cmd, self._setpoint_vector, steps, self.time_ns, self.step_ns,
                                   self._setpoint_time_ns + self.setpoint_timeout_ns, self.step_s, self._wind,
                                   self._att, self._att_state, self._inertia, self.mixer.params, self.body.params,
                                   self._limits, self._safe_bounds, self._inflated_blocks)
                if done:  # what _physics_step would have recorded for quiet steps
                    self.time_ns += done * self.step_ns
                    self.saturation, self.colliding = (), False
                    steps -= done
            if steps > 0:
                self._physics_step()
                steps -= 1
        self._record_history()

    def hold_steps(self, steps: int):
        """Time passes by `steps` physics steps with the vehicle held as it is, no physics (a realtime simulator's
        vehicle before its controller's first setpoint: free, it would sink and land by the failsafe before the
        controller runs). The setpoint timeout starts afresh at the end of the hold."""
        if self.stopped is not None:
            raise self.stopped
        self.time_ns += steps * self.step_ns
        self._setpoint_time_ns = self.time_ns
        self._record_history()

    def _record_history(self):
        if self.profile.odom_latency_s > 0:
            self._history.append((self.time_ns, self.state))
            oldest_needed_ns = self.time_ns - 2 * self.profile.odom_latency_s * 1e9
            while len(self._history) > 1 and self._history[1][0] <= oldest_needed_ns:
                self._history.popleft()

    # --- one physics step ---------------------------------------------------------------------------------

    def _physics_step(self):
        x = self._x
        if not self.failsafe_active and self.time_ns - self._setpoint_time_ns > self.setpoint_timeout_ns:
            self._enter_failsafe()
        if self.failsafe_active:
            if self.landed and self.armed:
                self.armed = False
                self._event('disarmed')
            sp = self._failsafe_input(x)
        else:
            sp = self._setpoint_vector
        if self.armed:
            flags = flag_names(command_rotors(x, sp, self._att, self._att_state, self.step_s, self._inertia,
                                              self.mixer.params, self._thrusts, self._w_cmd))
        else:
            self._w_cmd[:], flags = self.mixer.speed_min_radps, ()
        self._note_saturation(flags)
        if self._gusts is not None:
            self._wind = self.profile.wind_mps + self._gusts.step()
        rk4_step(x, self._w_cmd, self.step_s, NO_FORCE, self._wind, self.body.params)
        self.time_ns += self.step_ns
        if x[2] <= self.floor_z_m:
            self._ground_contact(x)
        elif self.landed:
            self.landed = False
            self._event('takeoff', position=x[0:3])
        total = float(x.sum())
        if not math.isfinite(total):
            self._stop(NON_FINITE, 'a state component is NaN or infinite')
        if x[3] * x[3] + x[4] * x[4] + x[5] * x[5] > self.max_speed_mps ** 2:
            self._stop(SPEED_LIMIT, f'speed above {self.max_speed_mps} m/s')
        if x[10] * x[10] + x[11] * x[11] + x[12] * x[12] > self.max_body_rate_radps ** 2:
            self._stop(BODY_RATE_LIMIT, f'body rate above {self.max_body_rate_radps} rad/s')
        if self._collision_world is not None:
            self._check_collision(x)

    def warm_up(self):
        """Loads (or, the first time, compiles) the step kernels now, on a throwaway copy of this simulator,
        so that start-up pays for it rather than the first lockstep step; one process at a time compiles
        (compiled.one_compiler)."""
        spare = Simulator(self.vehicle, physics_rate_hz=self.physics_rate_hz, initial_position=(0.0, 0.0, 1.0),
                          disturbances=self.profile)
        with one_compiler(os.path.dirname(__file__)):
            spare.advance_steps(1)
            spare._physics_step()

    def _enter_failsafe(self):
        self.failsafe_active = True
        self._failsafe_yaw = rotations.to_euler(self._x[6:10])[2]
        self._failsafe_quaternion = rotations.from_yaw(self._failsafe_yaw)
        hold = self._hold_position
        self._event('failsafe', detail={'reason': f'no setpoint for {self.setpoint_timeout_ns * 1e-9:.3f} s',
                                        'action': f'brake back to ({hold[0]:.2f}, {hold[1]:.2f}) m, descend, land, '
                                                  'disarm'})

    def _failsafe_input(self, x) -> np.ndarray:
        """The failsafe's attitude and thrust (module docstring): horizontal hold at p_hold, fixed descent rate."""
        if self.landed:
            return self._autopilot_input(self._failsafe_quaternion, 0.5 * GRAVITY_MPS2)
        a_x = FAILSAFE_POSITION_GAIN * (self._hold_position[0] - x[0]) - FAILSAFE_DAMPING_GAIN * x[3]
        a_y = FAILSAFE_POSITION_GAIN * (self._hold_position[1] - x[1]) - FAILSAFE_DAMPING_GAIN * x[4]
        f_z = min(max(GRAVITY_MPS2 + FAILSAFE_VELOCITY_GAIN * (-self.failsafe_descent_mps - x[5]),
                      0.5 * GRAVITY_MPS2), 1.5 * GRAVITY_MPS2)
        a_max = f_z * math.tan(FAILSAFE_MAX_TILT_RAD)
        norm = math.hypot(a_x, a_y)
        if norm > a_max:
            a_x, a_y = a_x * a_max / norm, a_y * a_max / norm
        z_b = np.array([a_x, a_y, f_z]) / math.sqrt(a_x * a_x + a_y * a_y + f_z * f_z)
        x_c = np.array([math.cos(self._failsafe_yaw), math.sin(self._failsafe_yaw), 0.0])
        y_b = np.cross(z_b, x_c)
        y_b /= np.linalg.norm(y_b)
        rotation = np.column_stack([np.cross(y_b, z_b), y_b, z_b])
        return self._autopilot_input(rotations.from_matrix(rotation), math.sqrt(a_x * a_x + a_y * a_y + f_z * f_z))

    def _ground_contact(self, x):
        """Keeps x on the floor; rests when the thrust's vertical part cannot lift the weight."""
        x[2] = self.floor_z_m
        impact_mps = float(x[5])
        qx, qy, qz, qw = x[6:10].tolist()
        lift_n = self.body.thrust_n(x) * (1 - 2 * (qx * qx + qy * qy))
        if lift_n <= self.plant_weight_n:
            if not self.landed:
                self.landed = True
                self._event('touchdown', position=x[0:3], detail={'vertical_speed_mps': round(impact_mps, 3)})
            yaw = math.atan2(2 * (qw * qz + qx * qy), 1 - 2 * (qy * qy + qz * qz))
            x[3:13] = [0.0, 0.0, 0.0, 0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2), 0.0, 0.0, 0.0]
        elif x[5] < 0.0:
            x[5] = 0.0

    def _check_collision(self, x):
        px, py, pz = x[0], x[1], x[2]
        b = self._safe_bounds
        suspect = not (b[0] < px < b[3] and b[1] < py < b[4] and pz < b[5]) or any(
            lx < px < hx and ly < py < hy and lz < pz < hz for lx, ly, lz, hx, hy, hz in self._inflated_blocks)
        hit = suspect and bool(self._collision_world.collides(np.array(x[0:3]), self.robot_radius_m)[0])
        if hit and not self.colliding:
            self.collision_count += 1
            distance = float(self._collision_world.obstacle_distance(np.array(x[0:3]))[0])
            self._event('collision', position=x[0:3], detail={'clearance_m': round(distance, 4),
                                                              'robot_radius_m': self.robot_radius_m})
        self.colliding = hit

    def _note_saturation(self, flags):
        self.saturation = flags
        if not flags:
            return
        self.saturated_steps += 1
        last = self._last_saturated_ns
        if last is None or self.time_ns - last > SATURATION_GAP_S * 1e9:
            self._event('saturation', detail={'reduced': list(flags)})
        self._last_saturated_ns = self.time_ns

    def _event(self, kind, position=None, detail=None):
        self.events.append(Event(kind, self.time_s, np.array(position if position is not None else self._x[0:3]),
                                 detail or {}))

    def _stop(self, reason, detail):
        self.stopped = SimulationStopped(reason, self.time_s, self._x[0:3].copy(), detail)
        self._event('stopped', detail={'reason': reason, 'detail': detail})
        raise self.stopped


def attitude_parameters(vehicle: Vehicle) -> np.ndarray:
    """The kernels' attitude-loop vector (ATT_*) of a vehicle."""
    loop = vehicle.attitude_loop
    kp, kd = vehicle.effective_attitude_gains()
    att = np.zeros(ATT_SIZE)
    att[ATT_TYPE] = LOOP_CODES[loop.type]
    att[ATT_KP:ATT_KP + 3], att[ATT_KD:ATT_KD + 3] = kp, kd
    att[ATT_TAU] = loop.time_constant_s
    att[ATT_FF_PQ] = float(loop.type == 'so3_pd' and loop.use_feedforward_rates)
    att[ATT_THRUST_SCALE] = 1.0 + vehicle.thrust_error
    return att


@njit
def _quat_mul(a, b):
    ax, ay, az, aw = a[0], a[1], a[2], a[3]
    bx, by, bz, bw = b[0], b[1], b[2], b[3]
    out = np.empty(4)
    out[0] = aw * bx + ax * bw + ay * bz - az * by
    out[1] = aw * by - ax * bz + ay * bw + az * bx
    out[2] = aw * bz + ax * by - ay * bx + az * bw
    out[3] = aw * bw - ax * bx - ay * by - az * bz
    return out


@njit
def _advance_target(target, quaternion_sp, tau_s, step_s):
    """The lag loop's target (quaternion target[0:4], body rates target[4:7]) one step towards the setpoint:
    rates = log(q_t^-1 q_sp) / tau, q_t <- q_t exp(rates dt) (first order on SO(3))."""
    conj = np.empty(4)
    conj[0], conj[1], conj[2], conj[3] = -target[0], -target[1], -target[2], target[3]
    e = _quat_mul(conj, quaternion_sp)
    if e[3] < 0.0:
        for i in range(4):
            e[i] = -e[i]
    v = math.sqrt(e[0] * e[0] + e[1] * e[1] + e[2] * e[2])
    angle = 2.0 * math.atan2(v, e[3])
    scale = angle / v / tau_s if v > 1e-12 else 2.0 / tau_s
    for i in range(3):
        target[4 + i] = scale * e[i]
    h = 0.5 * step_s
    d = np.empty(4)
    d[0], d[1], d[2] = h * target[4], h * target[5], h * target[6]
    d[3] = 1.0
    q = _quat_mul(target[0:4], d)
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    for i in range(4):
        target[i] = q[i] / n


@njit
def onboard_moments(x, setpoint, att, att_state, step_s, inertia):
    """The onboard attitude loop (ATT_TYPE): body moments (N m) from the state and the held setpoint."""
    kind = att[ATT_TYPE]
    rates = np.empty(3)
    if kind == LOOP_LAG:
        _advance_target(att_state, setpoint[0:4], att[ATT_TAU], step_s)
        rates[:] = att_state[4:7]
        return moments(x[6:10], x[10:13], att_state[0:4], rates, att[ATT_KP:ATT_KP + 3], att[ATT_KD:ATT_KD + 3],
                       inertia, True)
    ff = att[ATT_FF_PQ]
    rates[0], rates[1], rates[2] = ff * setpoint[5], ff * setpoint[6], setpoint[7]
    mx, my, mz = moments(x[6:10], x[10:13], setpoint[0:4], rates, att[ATT_KP:ATT_KP + 3], att[ATT_KD:ATT_KD + 3],
                         inertia, kind == LOOP_SO3_PD)
    if kind == LOOP_SO3_PD:  # + omega x I omega (diagonal I)
        p, q, r = x[10], x[11], x[12]
        ixx, iyy, izz = inertia[0, 0], inertia[1, 1], inertia[2, 2]
        mx += (izz - iyy) * q * r
        my += (ixx - izz) * r * p
        mz += (iyy - ixx) * p * q
    return mx, my, mz


@njit
def command_rotors(x, setpoint, att, att_state, step_s, inertia, mixer_params, thrusts_out, w_cmd_out):
    """The onboard autopilot: attitude-loop moments and the (scaled) collective thrust, mixed into rotor commands;
    mixer flag bits."""
    mx, my, mz = onboard_moments(x, setpoint, att, att_state, step_s, inertia)
    return rotor_commands(setpoint[4] * att[ATT_THRUST_SCALE], mx, my, mz, mixer_params, thrusts_out, w_cmd_out)


@njit
def quiet_steps(x, w_cmd, setpoint, steps, time_ns, step_ns, failsafe_after_ns, step_s, wind, att, att_state, inertia,
                mixer_params, body_params, limits, safe_bounds, inflated_blocks):
    """Up to `steps` physics steps on x and w_cmd (in place) while each is quiet: no failsafe due, no mixer
    saturation, above the floor, finite and within the speed and rate limits, not near an obstacle or the
    world's bounds. A step that is not quiet is undone, and left to Simulator._physics_step. Returns the
    number of steps done."""
    x_before, w_before, att_before, thrusts = np.empty(17), np.empty(4), np.empty(7), np.empty(4)
    for i in range(steps):
        if time_ns + i * step_ns > failsafe_after_ns:
            return i
        x_before[:] = x
        w_before[:] = w_cmd
        att_before[:] = att_state
        flags = command_rotors(x, setpoint, att, att_state, step_s, inertia, mixer_params, thrusts, w_cmd)
        rk4_step(x, w_cmd, step_s, NO_FORCE, wind, body_params)
        px, py, pz = x[0], x[1], x[2]
        b = safe_bounds
        suspect = not (b[0] < px < b[3] and b[1] < py < b[4] and pz < b[5])
        for k in range(inflated_blocks.shape[0]):
            lo_x, lo_y, lo_z, hi_x, hi_y, hi_z = inflated_blocks[k]
            suspect = suspect or (lo_x < px < hi_x and lo_y < py < hi_y and lo_z < pz < hi_z)
        if (flags != 0 or pz <= limits[LIMIT_FLOOR] or not math.isfinite(x.sum()) or suspect
                or x[3] * x[3] + x[4] * x[4] + x[5] * x[5] > limits[LIMIT_SPEED2]
                or x[10] * x[10] + x[11] * x[11] + x[12] * x[12] > limits[LIMIT_RATE2]):
            x[:] = x_before
            w_cmd[:] = w_before
            att_state[:] = att_before
            return i
    return steps
