"""The contract's one rule for a fleet vehicle's name (a ROS namespace component), used by the fleet file and
sim_node's vehicle_names alike."""

from quad_common import contract


def test_a_vehicle_name_is_one_ascii_namespace_component():
    assert all(contract.is_vehicle_name(n) for n in ('cf1', 'A', 'x_2', 'drone_B7'))
    # a digit first, a separator, a path, unicode letters (str.isalpha takes them; rcl does not), empty, not a str
    assert not any(contract.is_vehicle_name(n) for n in ('1a', 'cf-1', 'cf/1', 'café', 'é1', '', ' cf1', None, 3))


def test_a_topic_is_the_longest_contract_name_it_ends_with():
    """A namespaced topic is recognised by the contract name it ends with (/cf1/odom is an `odom`); where one name
    ends as another does (external/odometry, trajectory/waypoints), the longer one: an external odometry is never
    taken for the vehicle's odometry (the recorder paces the simulator on odom)."""
    for name in contract.TOPICS:
        assert contract.contract_name(name) == name
        if not name.startswith('/'):
            assert contract.contract_name(f'/cf1/{name}') == name
    assert contract.contract_name('/cf1/trajectory/waypoints') == contract.TRAJECTORY_WAYPOINTS
    assert contract.contract_name('external/odom') == contract.ODOM   # a user's topic so named is odometry
    assert contract.contract_name('/cf1/mocap') is None
