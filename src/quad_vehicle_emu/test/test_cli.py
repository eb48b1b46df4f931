"""Bad start-up values exit 2 with a message naming the field and the value."""

import pytest

from quad_vehicle_emu.mavlink_vehicle import main


@pytest.mark.parametrize('args, named', [
    (['--autopilot', 'ardupilot', '--param', 'COM_OF_LOSS_T=1'], 'COM_OF_LOSS_T'),   # a PX4 parameter
    (['--autopilot', 'px4', '--param', 'MPC_THR_HOVER=0.99'], 'MPC_THR_HOVER = 0.99'),
    (['--autopilot', 'ardupilot', '--param', 'GUID_TIMEOUT=nan'], 'GUID_TIMEOUT = nan'),
    (['--hover-throttle', '1.5'], 'hover_throttle = 1.5'),
    (['--drag-per-s', '-1'], '--drag-per-s = -1.0'),
    (['--estimator-velocity-noise-mps', '0,2,0'], '--estimator-velocity-noise-mps = [0.0, 2.0, 0.0]'),
    (['--realtime-priority', '100'], '--realtime-priority = 100'),
])
def test_bad_values_exit_2_naming_them(capsys, args, named):
    assert main([*args, '--url', 'udpout:127.0.0.1:9']) == 2
    assert named in capsys.readouterr().err


def test_malformed_param_is_an_argparse_error(capsys):
    with pytest.raises(SystemExit) as exc:
        main(['--param', 'GUID_OPTIONS'])
    assert exc.value.code == 2 and '--param needs NAME=NUMBER' in capsys.readouterr().err
