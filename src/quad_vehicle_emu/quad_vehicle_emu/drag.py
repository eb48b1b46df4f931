"""Linear air drag on the emulated vehicle, as PX4's SIH simulator flies it.

PX4 SIH's multicopter (src/modules/simulation/simulator_sih/sih.cpp, generate_force_and_torques) feels
`_Fa_E = -SIH_KDV * v_apparent`: a drag force linear in the airspeed, the same on every axis, SIH_KDV 1.0 N/(m/s)
on its SIH_MASS 1.0 kg by default (sih_params.yaml; the sihsim_quadx airframe keeps both), so the vehicle
decelerates at 1.0 (m/s^2) per m/s. A position controller's feed-forward does not know that force: at 0.8 m/s it
is 0.8 m/s^2 the position loop must supply from its error, which a soft loop (kp 2) pays for with tens of cm of
along-track lag and a disturbance observer removes.

quad_sim's rotor drag is linear in the body-frame airspeed, scaled by the summed rotor speed
(quad_sim.rigid_body: f = -c sum(w) v_b); near hover sum(w) is the hover's, so c = k m / sum(w_hover) gives a
deceleration of k per m/s, on the body axes rather than the world's (the same while the vehicle flies near level).
"""

import dataclasses
import math

from quad_common.types import GRAVITY_MPS2
from quad_sim.disturbances import DisturbanceProfile

PX4_SIH_DRAG_PER_S = 1.0   # SIH_KDV / SIH_MASS defaults: 1.0 N/(m/s) on 1.0 kg


def hover_rotor_speed_sum_radps(vehicle) -> float:
    """sum(w) of the four rotors holding the plant's weight (thrust_i = k_eta w_i^2)."""
    return 4.0 * math.sqrt(vehicle.plant_mass_kg * GRAVITY_MPS2 / (4.0 * vehicle.k_eta))


def check_drag(per_s: float):
    """ValueError naming --drag-per-s unless it is a number in [0, 10] (checked before the vehicle file is read)."""
    if not (math.isfinite(per_s) and 0.0 <= per_s <= 10.0):
        raise ValueError(f'--drag-per-s = {per_s!r} must be a number in [0, 10] (PX4 SIH: {PX4_SIH_DRAG_PER_S})')


def with_linear_drag(vehicle, per_s: float):
    """(vehicle, quad_sim DisturbanceProfile) decelerating at per_s (m/s^2 per m/s) on every axis near hover;
    per_s 0: the vehicle unchanged and no drag (the emulator's default). Raises ValueError naming the option."""
    check_drag(per_s)
    if per_s == 0.0:
        return vehicle, None
    c = per_s * vehicle.plant_mass_kg / hover_rotor_speed_sum_radps(vehicle)
    extra = {**vehicle.extra, 'aerodynamics': {'body_drag': [0.0, 0.0, 0.0], 'rotor_drag_xy': c, 'rotor_drag_z': c}}
    return dataclasses.replace(vehicle, extra=extra), DisturbanceProfile(name='linear drag', rotor_drag=True)
