"""mavlink_vehicle's real-time loop flies quad_vehicle_emu.plant.AutopilotPlant: on a clock in step with its physics,
a tick of the loop is a period of the plant as the offline harness flies it (what quad_bringup's emulated chain,
flown offline, stands for). No peer: the loop's telemetry goes nowhere."""

import numpy as np

from quad_common.paths import parameter_file
from quad_sim.simulator import Simulator
from quad_vehicle_emu import protocol as p
from quad_vehicle_emu.attitude import AttitudeResponse, emulated_vehicle
from quad_vehicle_emu.drag import with_linear_drag
from quad_vehicle_emu.estimator import Estimate
from quad_vehicle_emu.mavlink_vehicle import MavlinkVehicle, build_parser
from quad_vehicle_emu.plant import AutopilotPlant

# PX4 SIH's attitude chain, estimate and drag (docs/emulator.md), in the air: PX4 holds it (AUTO.LOITER). The
# estimate's lag falls between two ticks, so that the clocks' rounding (the loop's now, the simulator's ns) does not
# pick one sample or the next.
FLAGS = ['--url', 'udpin:127.0.0.1:0', '--initial-position', '0,0,1.5', '--attitude-tau-s', '0.05',
         '--attitude-dead-time-s', '0.07', '--rate-loop', 'px4-sih', '--drag-per-s', '1.0',
         '--estimator-lag-s', '0.145', '--estimator-wander-m', '0.18', '--estimator-wander-z-m', '0.3',
         '--estimator-wander-tau-s', '4', '--estimator-velocity-wander-mps', '0.2', '--seed', '3']
TICK_S = 0.01   # --loop-rate-hz 100: 5 physics steps at 500 Hz


def test_a_tick_of_the_loop_is_a_period_of_the_offline_plant():
    """The autopilot's hold flies the wandering estimate, disarmed (forced) for 0.2 s on the way and armed again;
    the same targets (none while disarmed: the response at rest) into an AutopilotPlant built from the same pieces,
    advanced a tick each, give the same truth and the same estimate."""
    args = build_parser().parse_args(FLAGS)
    vehicle = MavlinkVehicle(args)
    targets = []
    update = vehicle.ap.update

    def recorded(*a, **kw):
        targets.append(update(*a, **kw))
        return targets[-1]

    vehicle.ap.update = recorded
    airframe, drag = with_linear_drag(emulated_vehicle(parameter_file('--vehicle', args.vehicle), rate_loop='px4-sih'),
                                      1.0)
    sim = Simulator(airframe, physics_rate_hz=500.0, initial_position=(0.0, 0.0, 1.5), setpoint_timeout_s=1e6,
                    disturbances=drag)
    estimate = Estimate(0.145, 0.18, 0.3, 4.0, 3, velocity_wander_mps=0.2,
                        vision_timeout_s=vehicle.ap.position_timeout_s())
    plant = AutopilotPlant(sim, AttitudeResponse(0.05, sim.state.quaternion, 0.07), estimate, estimate_now=False)
    start = sim.state.position.copy()
    for k in range(1, 301):
        now = k * TICK_S + 1e-7   # just past the tick: the loop's physics catches up by one tick's steps
        if k in (150, 170):
            assert vehicle.ap.command(p.MAV_CMD_COMPONENT_ARM_DISARM, [float(k == 170), p.ARM_DISARM_FORCE_MAGIC],
                                      vehicle.plant.sim.landed, now) == p.MAV_RESULT_ACCEPTED
        vehicle.tick(now)
        sim.armed = targets[-1] is not None
        if targets[-1] is None:
            plant.rest(plant.observed().quaternion)
        else:
            plant.command(targets[-1])
        plant.advance(TICK_S)
        assert vehicle.plant.sim.time_ns == sim.time_ns
        truth, flown = vehicle.plant.state, plant.state
        np.testing.assert_allclose(truth.position, flown.position, rtol=0, atol=1e-12)
        np.testing.assert_allclose(truth.quaternion, flown.quaternion, rtol=0, atol=1e-12)
        seen, observed = vehicle.plant.observed(), plant.observed()
        np.testing.assert_allclose(seen.position, observed.position, rtol=0, atol=1e-12)
        np.testing.assert_allclose(seen.velocity, observed.velocity, rtol=0, atol=1e-12)
    assert sum(target is None for target in targets) == 20
    assert np.linalg.norm(sim.state.position - start) > 0.1   # it moved: the comparison is not of rest


def test_the_offline_chain_reads_the_emulators_own_plant_flags():
    """plant_flags reads a flag tuple as the emulator's parser does (its clock flag left to it); a flag that is
    neither the plant's nor the emulator's known non-plant one is refused by name, never skipped."""
    import pytest

    from quad_vehicle_emu.plant import plant_flags
    emulator = build_parser().parse_args(FLAGS)
    offline = plant_flags([*FLAGS[2:], '--clock-rate', '0.99'])
    assert {k: v for k, v in vars(offline).items()} == {k: getattr(emulator, k) for k in vars(offline)}
    with pytest.raises(ValueError, match="'--estimator-lag' is no plant flag"):
        plant_flags(['--estimator-lag', '0.15'])
