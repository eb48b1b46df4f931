"""Modes, arming, setpoint semantics and failsafes of PX4 and ArduPilot Copter, as their source behaves.

No sockets and no clock: times are seconds passed in by the caller. update() returns the attitude target and
specific force the autopilot's attitude loop is asked for (world ENU / body FLU, like quad_sim), or None when
disarmed. Every rule names the source file it follows (paths in PX4/PX4-Autopilot, ArduPilot/ardupilot).
"""

import collections
import math
from dataclasses import dataclass

import numpy as np

from quad_common import rotations
from quad_common.types import GRAVITY_MPS2, State
from quad_vehicle_emu import ned
from quad_vehicle_emu import protocol as p
from quad_vehicle_emu.onboard_params import ARDUCOPTER_PARAMS, PX4_PARAMS, ParameterStore

HOLD_TILT_MAX_RAD = math.radians(20.0)   # onboard position hold: gentle
HOLD_POS_P, HOLD_VEL_P = 1.0, 1.5        # horizontal position hold, 1/s and 1/s
LAND_DETECT_S = 1.0                      # ArduCopter land_detector.cpp LAND_DETECTOR_TRIGGER_SEC
PX4_NOAID_TIMEOUT_S = 5.0                # src/modules/ekf2/module.yaml EKF2_NOAID_TOUT: dead reckoning, then invalid
EKF_CHECK_S = 1.0                        # ArduCopter/ekf_check.cpp EKF_CHECK_ITERATIONS_MAX (10) at 10 Hz
COPTER_EXTNAV_TIMEOUT_S = 7.0            # libraries/AP_NavEKF3/AP_NavEKF3_core.cpp posRetryTimeNoVel_ms
PX4_MODES_NEED_POSITION = frozenset({'POSCTL', 'AUTO.LOITER', 'AUTO.MISSION', 'AUTO.RTL', 'AUTO.TAKEOFF'})
COPTER_MODES_NEED_POSITION = frozenset({'GUIDED', 'LOITER', 'POSHOLD', 'AUTO', 'RTL', 'CIRCLE', 'BRAKE', 'SMART_RTL'})


@dataclass
class Target:
    """What the attitude loop is asked for: ENU/FLU attitude, specific force, FLU body-rate feed-forward."""

    quaternion: np.ndarray
    specific_force_mps2: float
    body_rates: np.ndarray | None = None


@dataclass
class AttitudeTargetMsg:
    """A decoded SET_ATTITUDE_TARGET (MAVLink frames)."""

    type_mask: int
    q_wxyz: tuple
    rates_frd: tuple
    thrust: float
    thrust_body: tuple = (0.0, 0.0, 0.0)   # MAVLink 2 extension: FRD thrust, used by PX4 with THRUST_BODY_SET


class RateMeter:
    """Messages per second over the last window_s."""

    def __init__(self, window_s: float = 1.0):
        self.window_s = window_s
        self.times = collections.deque()

    def tick(self, now_s):
        self.times.append(now_s)

    def rate_hz(self, now_s) -> float:
        while self.times and self.times[0] < now_s - self.window_s:
            self.times.popleft()
        return len(self.times) / self.window_s


def _yaw(q) -> float:
    return float(rotations.to_euler(q)[2])


def _tilt_cos(q) -> float:
    return float(rotations.to_matrix(q)[2, 2])


def _unit_wxyz(q_wxyz) -> bool:
    """ArduPilot's Quaternion::is_unit_length: |q| within 1e-3 of 1 (libraries/AP_Math/quaternion.cpp)."""
    n = math.sqrt(sum(float(c) ** 2 for c in q_wxyz))
    return math.isfinite(n) and abs(n - 1.0) < 1e-3


class Autopilot:
    """What PX4 and ArduPilot share: arming bookkeeping, position hold and landing with an onboard loop."""

    autopilot_id = 0

    def __init__(self, params: ParameterStore, hover_throttle: float):
        if not 0.05 <= hover_throttle <= 0.95:
            raise ValueError(f'hover_throttle = {hover_throttle!r} must be in [0.05, 0.95]')
        self.params = params
        self.hover_throttle = float(hover_throttle)  # the vehicle's true hover throttle (physics)
        self.armed = False
        self.mode = ''
        self.hold_position = None
        self.log = []                    # (time_s, text): STATUSTEXT
        self.setpoints = RateMeter()
        self.setpoint_time_s = -math.inf
        self.landed_since_s = None
        self.external_pose_time_s = -math.inf   # last external-vision pose the estimator took

    def on_external_pose(self, now_s):
        """An external-vision pose arrived (PX4 ODOMETRY from a VISION estimator, ArduPilot
        VISION_POSITION_ESTIMATE); the estimator fuses it when its parameters say so."""
        self.external_pose_time_s = now_s

    def gps_aiding(self) -> bool:
        raise NotImplementedError

    def vision_aiding(self) -> bool:
        raise NotImplementedError

    def position_timeout_s(self) -> float:
        raise NotImplementedError

    def vision_axes(self) -> tuple[bool, bool, bool]:
        """The world axes (x, y, z) whose position estimate comes from the external-vision poses alone."""
        raise NotImplementedError

    def vision_delay_ms(self) -> float:
        """The pose's age the estimator assumes (EKF2_EV_DELAY / VISO_DELAY_MS)."""
        raise NotImplementedError

    def has_position(self, now_s) -> bool:
        """The estimator has a horizontal position: GPS aiding on (the emulator's GPS always has a fix), or
        vision aiding on and a pose fused within the estimator's timeout (dead reckoning until then)."""
        if self.gps_aiding():
            return True
        return self.vision_aiding() and now_s - self.external_pose_time_s <= self.position_timeout_s()

    def say(self, now_s, text):
        self.log.append((now_s, text))

    def _set_mode(self, mode, now_s, why):
        if mode != self.mode:
            self.mode = mode
            self.hold_position = None
            self.say(now_s, f'mode {mode}: {why}')

    def _arm(self, arm: bool, now_s, why='commanded'):
        if arm != self.armed:
            self.armed = arm
            self.say(now_s, ('armed' if arm else 'disarmed') + f': {why}')
            if not arm:
                self.on_disarm(now_s)

    def on_disarm(self, now_s):
        pass

    def _landed_for(self, landed: bool, now_s: float) -> float:
        if not landed:
            self.landed_since_s = None
            return 0.0
        if self.landed_since_s is None:
            self.landed_since_s = now_s
        return now_s - self.landed_since_s

    def _hold(self, state: State, descent_rate_mps=None) -> Target:
        """Onboard position hold over hold_position, or a descent at descent_rate_mps over it."""
        if self.hold_position is None:
            self.hold_position = state.position.copy()
        target = self.hold_position
        a = HOLD_POS_P * (target - state.position) - HOLD_VEL_P * state.velocity
        if descent_rate_mps is None:
            climb = p.PSC_POSZ_P * (target[2] - state.position[2])
        else:
            climb = -descent_rate_mps
        a[2] = p.PSC_VELZ_P * (climb - state.velocity[2])
        thrust = a + np.array([0.0, 0.0, GRAVITY_MPS2])
        thrust[2] = max(thrust[2], 0.2 * GRAVITY_MPS2)
        horizontal = np.linalg.norm(thrust[:2])
        limit = thrust[2] * math.tan(HOLD_TILT_MAX_RAD)
        if horizontal > limit:
            thrust[:2] *= limit / horizontal
        z_b = thrust / np.linalg.norm(thrust)
        yaw = _yaw(state.quaternion)
        x_c = np.array([math.cos(yaw), math.sin(yaw), 0.0])
        y_b = np.cross(z_b, x_c)
        y_b /= np.linalg.norm(y_b)
        R = np.column_stack([np.cross(y_b, z_b), y_b, z_b])
        return Target(rotations.from_matrix(R), float(np.linalg.norm(thrust)))

    def _descend_level(self, state: State, descent_rate_mps: float) -> Target:
        """Level at the current yaw, descending at descent_rate_mps, nothing holding it horizontally (it drifts)."""
        thrust = GRAVITY_MPS2 + p.PSC_VELZ_P * (-descent_rate_mps - state.velocity[2])
        return Target(rotations.from_yaw(_yaw(state.quaternion)), float(max(thrust, 0.2 * GRAVITY_MPS2)))

    @staticmethod
    def _idle(state) -> Target:
        return Target(rotations.from_yaw(_yaw(state.quaternion)), 0.0)


# --- PX4 -------------------------------------------------------------------------------------------------

class Px4(Autopilot):
    """PX4 v1.14+ multicopter commander (src/modules/commander/)."""

    autopilot_id = p.MAV_AUTOPILOT_PX4
    name = 'px4'

    def __init__(self, hover_throttle: float, params: dict | None = None, rp_rates_with_attitude: bool = True):
        """rp_rates_with_attitude False: as PX4's mavlink_receiver.cpp (handle_message_set_attitude_target) does,
        a SET_ATTITUDE_TARGET that carries an attitude keeps only its body yaw rate (as yaw_sp_move_rate, fed
        forward by mc_att_control); its roll and pitch rates are dropped (they reach vehicle_rates_setpoint only
        when the attitude is ignored). True (the default): all three are fed forward, as before."""
        super().__init__(ParameterStore(PX4_PARAMS, bytewise_ints=True), hover_throttle)
        self.rp_rates_with_attitude = bool(rp_rates_with_attitude)
        self.params.set('MPC_THR_HOVER', hover_throttle)   # the hover thrust estimator has converged
        for k, v in (params or {}).items():
            self.params.set(k, v)
        # no RC in the emulator: it boots in Hold (POSCTL would need manual control; mode_requirements.cpp)
        self.mode = 'AUTO.LOITER'
        self.user_mode = 'AUTO.LOITER'          # UserModeIntention::_user_intented_nav_state
        self.mode_after_disarm = 'AUTO.LOITER'  # UserModeIntention::_nav_state_after_disarming
        self.failsafe_mode = None               # failsafe action mode while active (clears on mode change/disarm)
        self.setpoint = None                    # (q_enu, thrust, rates_flu or None)

    @property
    def custom_mode(self) -> int:
        return p.px4_custom_mode(self.mode)

    @property
    def base_mode(self) -> int:
        return (p.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | p.MAV_MODE_FLAG_STABILIZE_ENABLED
                | (p.MAV_MODE_FLAG_SAFETY_ARMED if self.armed else 0))

    def offboard_signal(self, now_s) -> bool:
        """offboardCheck.cpp: the last setpoint is younger than COM_OF_LOSS_T (what the failsafe watches)."""
        return now_s - self.setpoint_time_s < self.params['COM_OF_LOSS_T']

    def gps_aiding(self) -> bool:
        return bool(int(self.params['EKF2_GPS_CTRL']) & 1)    # bit 0: lon/lat

    def vision_aiding(self) -> bool:
        return bool(int(self.params['EKF2_EV_CTRL']) & 1)     # bit 0: horizontal position

    def position_timeout_s(self) -> float:
        return PX4_NOAID_TIMEOUT_S

    def vision_axes(self) -> tuple[bool, bool, bool]:
        """Horizontal: EKF2_EV_CTRL bit 0 with GPS lon/lat off; vertical: EKF2_EV_CTRL bit 1 with EKF2_HGT_REF 3
        (vision). Where GPS aiding is on, the GPS-like estimate stays (both fused: the GPS dominates outdoors)."""
        horizontal = self.vision_aiding() and not self.gps_aiding()
        vertical = bool(int(self.params['EKF2_EV_CTRL']) & 2) and int(self.params['EKF2_HGT_REF']) == 3
        return horizontal, horizontal, vertical

    def vision_delay_ms(self) -> float:
        return float(self.params['EKF2_EV_DELAY'])

    def can_run(self, mode, now_s) -> bool:
        """Entering OFFBOARD (switch or arm) also needs the stream at > 2 Hz, as the user guide requires. Modes
        that need a local position (mode_requirements.cpp) cannot run without one (modeCheck.cpp); OFFBOARD with
        attitude setpoints needs none (offboardCheck.cpp asks for it only with position control)."""
        if mode in p.PX4_NEEDS_MANUAL_CONTROL:
            return False
        if mode in PX4_MODES_NEED_POSITION and not self.has_position(now_s):
            return False
        if mode == 'OFFBOARD':
            return self.offboard_signal(now_s) and self.setpoints.rate_hz(now_s) > p.PX4_OFFBOARD_MIN_RATE_HZ
        return True

    def can_arm(self, now_s) -> bool:
        """HealthAndArmingChecks: the current mode must be able to run and must not prevent arming."""
        return self.mode not in p.PX4_PREVENT_ARMING and self.can_run(self.mode, now_s)

    def sys_status_bits(self, now_s) -> tuple[int, int, int]:
        """src/modules/mavlink/streams/SYS_STATUS.hpp: only the health bit of PREARM_CHECK, set when the current
        nav state can arm (health_report.can_arm_mode_flags); EXTENSION_USED in all three words."""
        present = enabled = health = p.SENSORS_BASIC | p.MAV_SYS_STATUS_EXTENSION_USED
        if self.can_arm(now_s):
            health |= p.MAV_SYS_STATUS_PREARM_CHECK
        return present, enabled, health

    def on_attitude_target(self, msg: AttitudeTargetMsg, now_s):
        """mavlink_receiver.cpp handle_message_set_attitude_target: always feeds offboard_control_mode (the
        signal that keeps OFFBOARD available); MC thrust_body[2] = -thrust. Raises ValueError on NaN/zero q."""
        mask = msg.type_mask
        rates = None
        if mask & p.TYPEMASK_RATES_IGNORE != p.TYPEMASK_RATES_IGNORE:
            rates = ned.frd_to_flu([0.0 if mask & b else r for b, r in
                                    zip((1, 2, 4), msg.rates_frd)])
        if not math.isfinite(msg.thrust) or (rates is not None and not np.all(np.isfinite(rates))):
            raise ValueError(f'SET_ATTITUDE_TARGET thrust {msg.thrust} / rates {msg.rates_frd} not finite')
        q = None
        if not mask & p.TYPEMASK_ATTITUDE_IGNORE:
            norm = math.sqrt(sum(float(c) ** 2 for c in msg.q_wxyz))
            if not (math.isfinite(norm) and norm > 1e-6):
                raise ValueError(f'SET_ATTITUDE_TARGET q = {list(msg.q_wxyz)} is not a rotation')
            q = ned.attitude_from_ned_wxyz(msg.q_wxyz)
            if rates is not None and not self.rp_rates_with_attitude:
                rates = np.array([0.0, 0.0, rates[2]])   # mavlink_receiver: only yaw_sp_move_rate survives
        # THRUST_BODY_SET: thrust_body (FRD, -z is up) instead of thrust (mavlink_receiver.cpp)
        thrust = -float(msg.thrust_body[2]) if mask & p.TYPEMASK_THRUST_BODY_SET else float(msg.thrust)
        if not math.isfinite(thrust):
            raise ValueError(f'SET_ATTITUDE_TARGET thrust_body {list(msg.thrust_body)} not finite')
        self.setpoint = (q, float(np.clip(thrust, 0.0, 1.0)), rates)
        self.setpoint_time_s = now_s
        self.setpoints.tick(now_s)

    def _change_user_mode(self, mode, now_s, why) -> bool:
        """UserModeIntention::change: always allowed disarmed; armed only when the mode can run."""
        if self.armed and not self.can_run(mode, now_s):
            self.say(now_s, f'{mode} rejected: ' + ('no offboard signal' if mode == 'OFFBOARD' else 'cannot run'))
            return False
        self.user_mode = mode
        if mode not in p.PX4_PREVENT_ARMING:
            self.mode_after_disarm = mode
        self.failsafe_mode = None
        self._set_mode(mode, now_s, why)
        return True

    def command(self, command: int, params, landed: bool, now_s: float) -> int:
        if command == p.MAV_CMD_COMPONENT_ARM_DISARM:
            arm = params[0] > 0.5
            forced = int(params[1]) == p.ARM_DISARM_FORCE_MAGIC
            if arm and not self.armed and not forced and not self.can_arm(now_s):
                if self.mode in PX4_MODES_NEED_POSITION and not self.has_position(now_s):
                    # checks/modeCheck.cpp, then Commander::arm
                    self.say(now_s, 'Preflight Fail: No valid local position estimate')
                    self.say(now_s, 'Arming denied: Resolve system health failures first')
                else:
                    self.say(now_s, f'Arming denied: mode {self.mode} cannot arm')
                return p.MAV_RESULT_DENIED
            if not arm and self.armed and not landed and not forced:
                return p.MAV_RESULT_DENIED
            self._arm(arm, now_s)
            return p.MAV_RESULT_ACCEPTED
        if command == p.MAV_CMD_DO_SET_MODE:
            if int(params[0]) & p.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED == 0:
                return p.MAV_RESULT_DENIED
            mode = p.px4_mode_name(params[1], params[2])
            if mode is None:
                return p.MAV_RESULT_DENIED
            return p.MAV_RESULT_ACCEPTED if self._change_user_mode(mode, now_s, 'commanded') else p.MAV_RESULT_DENIED
        if command == p.MAV_CMD_NAV_LAND:   # Commander: VEHICLE_CMD_NAV_LAND -> user intention AUTO_LAND
            return (p.MAV_RESULT_ACCEPTED if self._change_user_mode('AUTO.LAND', now_s, 'NAV_LAND')
                    else p.MAV_RESULT_DENIED)
        return p.MAV_RESULT_UNSUPPORTED

    def on_disarm(self, now_s):
        """UserModeIntention::onDisarm: back to the last user mode that allows arming (e.g. OFFBOARD)."""
        self.failsafe_mode = None
        self.user_mode = self.mode_after_disarm
        self._set_mode(self.user_mode, now_s, 'user intention after disarm')

    def update(self, state: State, landed: bool, now_s: float, dt_s: float = 0.01) -> Target | None:
        landed_s = self._landed_for(landed, now_s)
        if self.armed and self.mode in ('AUTO.LAND', 'AUTO.PRECLAND', *p.PX4_NEEDS_MANUAL_CONTROL) and \
                landed_s > self.params['COM_DISARM_LAND']:
            self._arm(False, now_s, 'landed')   # COM_DISARM_LAND after the land detector
        if not self.armed:
            return None
        if self.mode in PX4_MODES_NEED_POSITION and not self.has_position(now_s):
            # failsafe/framework.cpp checkModeFallback: the mode cannot run; with no position (and no RC) the
            # fallback is Descend, which PX4 reports as AUTO.LAND (px4_custom_mode.h)
            self.failsafe_mode = 'AUTO.LAND'
            self._set_mode('AUTO.LAND', now_s, 'failsafe: No valid local position estimate, descending')
        if self.user_mode == 'OFFBOARD' and self.failsafe_mode is None and not self.offboard_signal(now_s):
            # commander/failsafe/failsafe.cpp fromOffboardLossActParam; framework.cpp modeCanRun leaves manual
            # control out ("handled separately"), so Position (0) runs POSCTL without RC too
            action = p.PX4_OFFBOARD_LOSS_ACTIONS[int(self.params['COM_OBL_RC_ACT'])]
            if action == 'DISARM':
                self._arm(False, now_s, 'offboard lost')
                return None
            self.failsafe_mode = 'AUTO.LAND' if action == 'TERMINATE' else action
            self._set_mode(self.failsafe_mode, now_s, f'failsafe: offboard lost ({self.params["COM_OF_LOSS_T"]} s)')
        if self.mode == 'OFFBOARD' and self.setpoint is not None:
            q, thrust, rates = self.setpoint
            if q is None:
                q = state.quaternion
            # PX4 multicopter: normalised collective thrust, linear about hover (no tilt compensation)
            return Target(q, thrust * GRAVITY_MPS2 / self.hover_throttle, rates)
        if self.mode in p.PX4_NEEDS_MANUAL_CONTROL:
            # a stick mode with no sticks (the emulator has no RC): as PX4 v1.16 SIH flew it with the bridge
            # killed, descending level, nothing holding it horizontally (it drifts)
            return self._idle(state) if landed else self._descend_level(state, self.params['MPC_LAND_SPEED'])
        if self.mode in ('AUTO.LAND', 'AUTO.PRECLAND', 'AUTO.RTL'):
            if not self.has_position(now_s):   # Descend: level, nothing holding it horizontally
                return self._idle(state) if landed else self._descend_level(state, self.params['MPC_LAND_SPEED'])
            return self._idle(state) if landed and self.hold_position is not None and landed_s > 0.5 else \
                self._hold(state, self.params['MPC_LAND_SPEED'])
        if landed:
            return self._idle(state)
        return self._hold(state)


# --- ArduPilot Copter --------------------------------------------------------------------------------------

class ArduCopter(Autopilot):
    """ArduCopter 4.x (ArduCopter/, libraries/)."""

    autopilot_id = p.MAV_AUTOPILOT_ARDUPILOTMEGA
    name = 'ardupilot'

    def __init__(self, hover_throttle: float, params: dict | None = None):
        super().__init__(ParameterStore(ARDUCOPTER_PARAMS, bytewise_ints=False), hover_throttle)
        self.params.set('MOT_THST_HOVER', min(max(hover_throttle, 0.125), 0.6875))  # learnt (MOT_HOVER_LEARN 2)
        for k, v in (params or {}).items():
            self.params.set(k, v)
        self.mode = 'STABILIZE'
        self.angle = None      # guided_angle_state: (q_enu or None, climb_rate_or_thrust, rates_flu, use_thrust)
        self.alt_target = None  # AC_PosControl z target while the climb rate is integrated
        self.position_lost_s = None  # since when the EKF has had no position (armed)

    @property
    def custom_mode(self) -> int:
        return p.COPTER_MODES[self.mode]

    @property
    def base_mode(self) -> int:
        # GCS_MAVLINK_Copter::base_mode(): custom mode enabled, stabilize, guided in guided modes, armed flag
        return (p.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | p.MAV_MODE_FLAG_STABILIZE_ENABLED
                | (p.MAV_MODE_FLAG_GUIDED_ENABLED if self.mode in p.COPTER_GUIDED_MODES else 0)
                | (p.MAV_MODE_FLAG_SAFETY_ARMED if self.armed else 0))

    def sys_status_bits(self, now_s) -> tuple[int, int, int]:
        """libraries/GCS_MAVLink/GCS.cpp update_sensor_status_flags: PREARM_CHECK present always, enabled when
        arming checks are enabled (ARMING_CHECK default 1), healthy when armed or the checks pass."""
        present = enabled = health = p.SENSORS_BASIC | p.MAV_SYS_STATUS_PREARM_CHECK
        return present, enabled, health

    def gps_aiding(self) -> bool:
        return int(self.params['EK3_SRC1_POSXY']) == 3          # AP_NavEKF_Source: 3 GPS

    def vision_aiding(self) -> bool:
        return int(self.params['EK3_SRC1_POSXY']) == 6 and int(self.params['VISO_TYPE']) > 0   # 6 ExternalNAV

    def position_timeout_s(self) -> float:
        return COPTER_EXTNAV_TIMEOUT_S

    def vision_axes(self) -> tuple[bool, bool, bool]:
        """AP_NavEKF_Source: EK3_SRC1_POSXY 6 and EK3_SRC1_POSZ 6 (ExternalNAV) with VISO_TYPE set."""
        horizontal = self.vision_aiding()
        vertical = int(self.params['EK3_SRC1_POSZ']) == 6 and int(self.params['VISO_TYPE']) > 0
        return horizontal, horizontal, vertical

    def vision_delay_ms(self) -> float:
        return float(self.params['VISO_DELAY_MS'])

    @property
    def use_thrust(self) -> bool:
        return bool(int(self.params['GUID_OPTIONS']) & p.GUID_OPTIONS_THRUST_AS_THRUST)

    def _guided_init(self, now_s):
        """mode_guided.cpp init(true) / angle_control_start: level at the current yaw, climb 0, from now."""
        self.angle = (None, 0.0, None, False)
        self.setpoint_time_s = now_s
        self.alt_target = None

    def on_attitude_target(self, msg: AttitudeTargetMsg, now_s):
        """ArduCopter/GCS_Mavlink.cpp handle_message_set_attitude_target."""
        if self.mode not in p.COPTER_GUIDED_MODES:
            return                                           # not in Guided: ignored
        mask = msg.type_mask
        if mask & p.TYPEMASK_THROTTLE_IGNORE:
            self._guided_init(now_s)                         # "The throttle input is not defined"
            raise ValueError('SET_ATTITUDE_TARGET with THROTTLE_IGNORE: guided target reset')
        q = None
        if not mask & p.TYPEMASK_ATTITUDE_IGNORE:
            if not _unit_wxyz(msg.q_wxyz):
                self._guided_init(now_s)
                raise ValueError(f'SET_ATTITUDE_TARGET q = {list(msg.q_wxyz)} is not unit length: guided target reset')
            q = ned.attitude_from_ned_wxyz(msg.q_wxyz)
        ignored = mask & p.TYPEMASK_RATES_IGNORE
        if ignored == 0:
            rates = ned.frd_to_flu(msg.rates_frd)
        elif ignored == p.TYPEMASK_RATES_IGNORE:
            rates = None
        else:
            self._guided_init(now_s)
            raise ValueError(f'SET_ATTITUDE_TARGET type_mask {mask}: body rates partly ignored')
        thrust = float(msg.thrust)
        if not math.isfinite(thrust) or (rates is not None and not np.all(np.isfinite(rates))):
            raise ValueError(f'SET_ATTITUDE_TARGET thrust {msg.thrust} / rates {msg.rates_frd} not finite')
        if self.use_thrust:
            value = float(np.clip(thrust, -1.0, 1.0))
        else:                                                # thrust -> climb rate (m/s)
            thrust = float(np.clip(thrust, 0.0, 1.0))
            if thrust >= 0.5:
                value = (thrust - 0.5) * 2.0 * self.params['WPNAV_SPEED_UP'] / 100.0
            else:
                value = (thrust - 0.5) * 2.0 * self.params['WPNAV_SPEED_DN'] / 100.0
        if self.angle is None or self.angle[3] != self.use_thrust:
            self.alt_target = None
        self.angle = (q, value, rates, self.use_thrust)
        self.setpoint_time_s = now_s
        self.setpoints.tick(now_s)

    def command(self, command: int, params, landed: bool, now_s: float) -> int:
        if command == p.MAV_CMD_COMPONENT_ARM_DISARM:
            arm = params[0] > 0.5
            forced = int(params[1]) == p.ARM_DISARM_FORCE_MAGIC
            if arm and not self.armed and self.mode in p.COPTER_NO_ARMING and not forced:
                self.say(now_s, f'Arm: Mode not armable ({self.mode})')
                return p.MAV_RESULT_FAILED
            if arm and not self.armed and self.mode in COPTER_MODES_NEED_POSITION and not forced and \
                    not self.has_position(now_s):
                # AP_Arming_Copter.cpp mandatory_gps_checks: the mode requires GPS and position_ok() is false
                self.say(now_s, 'PreArm: Need Position Estimate')
                return p.MAV_RESULT_FAILED
            if not arm and self.armed and not landed and not forced:
                return p.MAV_RESULT_FAILED
            self._arm(arm, now_s)
            return p.MAV_RESULT_ACCEPTED
        if command == p.MAV_CMD_DO_SET_MODE:
            names = {v: k for k, v in p.COPTER_MODES.items()}
            mode = names.get(int(params[1])) if int(params[0]) & p.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED else None
            if mode is None:
                return p.MAV_RESULT_FAILED
            if mode in COPTER_MODES_NEED_POSITION and not self.has_position(now_s):
                # mode.cpp Copter::set_mode: requires_GPS() and !position_ok() -> mode_change_failed
                self.say(now_s, f'Mode change to {mode} failed: requires position')
                return p.MAV_RESULT_FAILED
            self._enter(mode, now_s, 'commanded')
            return p.MAV_RESULT_ACCEPTED
        if command == p.MAV_CMD_NAV_LAND:
            self._enter('LAND', now_s, 'NAV_LAND')
            return p.MAV_RESULT_ACCEPTED
        return p.MAV_RESULT_UNSUPPORTED

    def _enter(self, mode, now_s, why):
        if mode == 'GUIDED_NOGPS':
            self._guided_init(now_s)   # ModeGuidedNoGPS::init -> angle_control_start
        elif mode == 'GUIDED':
            self.angle = None          # ModeGuided::init -> position hold until a target arrives
        self._set_mode(mode, now_s, why)

    def _vertical(self, state: State, climb_rate_mps: float, dt_hint_s: float = 0.01) -> float:
        """AC_PosControl z: the target altitude integrates the climb rate; P on it, P on the climb rate."""
        if self.alt_target is None:
            self.alt_target = float(state.position[2])
        self.alt_target += climb_rate_mps * dt_hint_s
        vel = climb_rate_mps + p.PSC_POSZ_P * (self.alt_target - state.position[2])
        return GRAVITY_MPS2 + p.PSC_VELZ_P * (vel - state.velocity[2])

    def update(self, state: State, landed: bool, now_s: float, dt_s: float = 0.01) -> Target | None:
        landed_s = self._landed_for(landed, now_s)
        if self.armed and self.mode == 'LAND' and landed_s > LAND_DETECT_S:
            self._arm(False, now_s, 'landed')   # ModeLand: disarm once land_complete
        if not self.armed:
            return None
        if self.has_position(now_s):
            self.position_lost_s = None
        elif self.position_lost_s is None:
            self.position_lost_s = now_s
        if self.mode in COPTER_MODES_NEED_POSITION and self.position_lost_s is not None and \
                now_s - self.position_lost_s >= EKF_CHECK_S:
            # ekf_check.cpp: position bad for EKF_CHECK_ITERATIONS_MAX checks at 10 Hz, failsafe_ekf_event with
            # FS_EKF_ACTION 1 (default): set_mode_land_with_pause, landing without GPS
            self.say(now_s, 'EKF Failsafe')
            self._enter('LAND', now_s, 'EKF failsafe')
        if self.mode in p.COPTER_GUIDED_MODES and self.angle is not None:
            return self._angle_control(state, now_s, dt_s)
        if self.mode == 'LAND':
            if landed and landed_s > 0.5:
                return self._idle(state)
            if not self.has_position(now_s):    # mode_land.cpp nogps_run: level, descending, drifting
                return self._descend_level(state, self.params['LAND_SPEED'] / 100.0)
            return self._hold(state, self.params['LAND_SPEED'] / 100.0)
        if landed:
            return self._idle(state)
        return self._hold(state)

    def _angle_control(self, state, now_s, dt_s) -> Target:
        """mode_guided.cpp angle_control_run."""
        q, value, rates, use_thrust = self.angle
        if now_s - self.setpoint_time_s > self.params['GUID_TIMEOUT'] or (q is None and rates is None):
            # timeout (or no target yet): level at the current yaw, no rates, climb rate 0; thrust mode is dropped
            if use_thrust:
                self.alt_target = None
                self.angle = (q, 0.0, None, False)
            q, rates, value, use_thrust = rotations.from_yaw(_yaw(state.quaternion)), None, 0.0, False
        if q is None:
            q = state.quaternion
        tilt_cos = _tilt_cos(state.quaternion)
        boost = 1.0 / max(tilt_cos, p.ANGLE_BOOST_MIN_COS) if self.params['ATC_ANGLE_BOOST'] else 1.0
        if use_thrust:   # set_throttle_out(thrust, apply_angle_boost=true): boost with the actual tilt
            throttle = max(value, 0.0) * boost
            f = throttle * GRAVITY_MPS2 / self.hover_throttle
        else:
            f = self._vertical(state, value, dt_s) * boost
        return Target(q, float(max(f, 0.0)), rates)


def make_autopilot(flavour: str, hover_throttle: float, params: dict | None = None,
                   rp_rates_with_attitude: bool = True) -> Autopilot:
    """rp_rates_with_attitude: PX4 only (Px4)."""
    if flavour == 'px4':
        return Px4(hover_throttle, params, rp_rates_with_attitude)
    if flavour == 'ardupilot':
        return ArduCopter(hover_throttle, params)
    raise ValueError(f'autopilot = {flavour!r}: px4 or ardupilot')
