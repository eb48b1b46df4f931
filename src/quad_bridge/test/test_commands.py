"""The MAVLink commands the bridge sends (quad_bridge.commands.VehicleCommander), on the real backends, against a
recording client: what goes on the wire, what the vehicle is taken to be in, what the parameter check decides."""

from bridge_fakes import Client, bridge

from quad_bridge.ardupilot import ArduPilot
from quad_bridge.backend import MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, rate_interval_us
from quad_bridge.mavlink_client import mavlink
from quad_bridge.px4 import Px4

REAL32 = mavlink.MAV_PARAM_TYPE_REAL32


def test_set_mode_sends_do_set_mode_and_the_vehicle_is_taken_to_be_in_it_until_refused():
    b = bridge(Px4(), client=Client(result=mavlink.MAV_RESULT_DENIED))
    b.vehicle.heartbeat(Px4().custom_mode('POSCTL'), True, b.now_s())
    main, sub = Px4().mode_params('AUTO.LAND')
    b.commander.set_mode('AUTO.LAND', wait=False)
    assert b.client.commands[-1] == (1, 1, mavlink.MAV_CMD_DO_SET_MODE,
                                     [MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, main, sub], None)
    assert b.vehicle.mode_now(b.now_s()) == 'AUTO.LAND'      # no wait: no ACK read, the command holds
    assert b.commander.set_mode('AUTO.LOITER') == mavlink.MAV_RESULT_DENIED
    assert b.client.commands[-1][-1] == 3.0                   # waits command_timeout_s
    assert b.vehicle.mode_now(b.now_s()) == 'POSCTL'          # refused: the heartbeat's mode again


def test_arm_and_disarm_are_component_arm_disarm_with_1_and_0():
    b = bridge(ArduPilot())
    b.commander.arm(True)
    b.commander.arm(False)
    assert [c[2:] for c in b.client.commands] == [(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, [1.0], 3.0),
                                                  (mavlink.MAV_CMD_COMPONENT_ARM_DISARM, [0.0], 3.0)]


def test_telemetry_groups_are_requested_at_their_share_or_2_hz_and_a_refusal_is_a_warning():
    b = bridge(Px4(), client=Client(result=mavlink.MAV_RESULT_UNSUPPORTED))
    shares = {g.name: g.share for g in Px4().telemetry}
    for name, share in shares.items():
        assert b.commander.group_rate_hz(name) == (50.0 * share if share else 2.0)
    b.commander.request_messages(('ODOMETRY',), 50.0)
    assert b.client.commands == [(1, 1, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL,
                                  [mavlink.MAVLINK_MSG_ID_ODOMETRY, rate_interval_us(50.0)], 1.0)]
    assert b.log.lines == [('warn', 'ODOMETRY at 50 Hz: MAV_RESULT_UNSUPPORTED')]
    b.client.result = None                 # unanswered: the stream fall-back notices, no warning
    b.commander.request_messages(('ODOMETRY',), 50.0)
    assert len(b.log.lines) == 1


def test_connect_requests_every_groups_first_set_then_reads_the_parameters():
    from quad_bridge.telemetry_streams import StreamSelector
    b = bridge(Px4(), params={'vehicle_params': 'ignore'})
    streams = StreamSelector(Px4().telemetry)
    b.commander.connect(streams)
    requested = [c[3][0] for c in b.client.commands]
    first = [getattr(mavlink, f'MAVLINK_MSG_ID_{m}') for g in Px4().telemetry for m in g.options[0]]
    assert requested == first and streams.requested_s
    assert b.commander.param_check is not None and not b.client.reads   # ignore: nothing read


def test_parameter_problems_refuse_offboard_and_are_logged_and_read_again_for_offboard():
    px4 = Px4()
    names = px4.param_names(bridge(px4).commander.config)
    values = {'MPC_THR_HOVER': 0.7, 'COM_OF_LOSS_T': 1.0}
    client = Client(params={n: (values.get(n, 0.0), REAL32) for n in names})
    b = bridge(px4, client=client)
    check = b.commander.read_vehicle_params()
    assert check.problems and b.commander.param_check is check
    assert b.vehicle.status.params['MPC_THR_HOVER'] == 0.7
    assert ('error', f'offboard will be refused: {check.problems[0]}') in b.log.lines
    b.commander.current_check()
    assert len(client.reads) == 2          # offboard reads the vehicle's values again


def test_adopted_parameters_become_the_flying_configuration():
    px4 = Px4()
    names = px4.param_names(bridge(px4).commander.config)
    values = {'MPC_THR_HOVER': 0.7, 'COM_OF_LOSS_T': 1.0}
    b = bridge(px4, params={'vehicle_params': 'adopt'},
               client=Client(params={n: (values.get(n, 0.0), REAL32) for n in names}))
    assert b.commander.flying_config.hover_throttle == 0.5
    b.commander.read_vehicle_params()
    assert b.commander.flying_config.hover_throttle == 0.7 and b.commander.config.hover_throttle == 0.5
