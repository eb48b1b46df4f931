"""The contract's one rule for a fleet vehicle's name (a ROS namespace component), used by the fleet file and
sim_node's vehicle_names alike."""

from quad_common import contract


def test_a_vehicle_name_is_one_ascii_namespace_component():
    assert all(contract.is_vehicle_name(n) for n in ('cf1', 'A', 'x_2', 'drone_B7'))
    # a digit first, a separator, a path, unicode letters (str.isalpha takes them; rcl does not), empty, not a str
    assert not any(contract.is_vehicle_name(n) for n in ('1a', 'cf-1', 'cf/1', 'café', 'é1', '', ' cf1', None, 3))
