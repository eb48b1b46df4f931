"""A launch file's nodes started as launch_ros starts them (launch_standin: the installed console script,
`--ros-args -r __node:=NAME [-r __ns:=/NS] --params-file ...`), and every parameter of each read back through its
parameter services, as `ros2 param dump` does (list_parameters, then get_parameters of every name)."""

import subprocess
import time
from contextlib import contextmanager
from pathlib import Path

import rclpy
from ament_index_python.packages import get_package_prefix
from launch_standin import evaluate
from rcl_interfaces.srv import GetParameters, ListParameters
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import parameter_value_to_python

from quad_bringup.emulated.vehicle_graph import WAIT_S, terminate
from quad_common.ros.testing import isolated_domain

PUSHED = 'uav2'
RESEND_S = 5.0   # a parameter service's request is asked again after this long without an answer


def pushed_launch_file(tmp_path: Path, launch_file: Path, push: str = PUSHED, **arguments) -> Path:
    """A launch file that includes launch_file under PushRosNamespace(push) in a GroupAction: the standard way
    to run a second vehicle."""
    path = tmp_path / f'pushed_{Path(launch_file).name}'
    path.write_text(
        'from launch import LaunchDescription\n'
        'from launch.actions import GroupAction, IncludeLaunchDescription\n'
        'from launch.launch_description_sources import PythonLaunchDescriptionSource\n'
        'from launch_ros.actions import PushRosNamespace\n\n\n'
        'def generate_launch_description():\n'
        f'    return LaunchDescription([GroupAction([PushRosNamespace({push!r}), IncludeLaunchDescription(\n'
        f'        PythonLaunchDescriptionSource({str(launch_file)!r}),\n'
        f'        launch_arguments={sorted(arguments.items())!r})])])\n')
    return path


class ParameterReader:
    """A node in `domain` that reads remote nodes' parameters through their parameter services."""

    def __init__(self, domain: int):
        self.ctx = rclpy.Context()
        rclpy.init(context=self.ctx, domain_id=domain)
        self.node = rclpy.create_node('parameter_reader', context=self.ctx)
        self.executor = SingleThreadedExecutor(context=self.ctx)
        self.executor.add_node(self.node)

    def _call(self, client, request, what, alive):
        """The first answer to `request`, asked again every RESEND_S: a request sent as soon as the service is
        discovered can be lost over DDS (the server's reply writer may not have matched this client's reader yet,
        and the reply is then dropped), and list_parameters / get_parameters are safe to repeat."""
        deadline = time.monotonic() + WAIT_S
        while not client.wait_for_service(timeout_sec=0.1):
            alive()
            if time.monotonic() > deadline:
                raise AssertionError(f'no {what} service within {WAIT_S} s')
        futures, resend_at = [], 0.0
        while not any(f.done() for f in futures):
            alive()
            now = time.monotonic()
            if now > deadline:
                raise AssertionError(f'{what}: no answer within {WAIT_S} s to {len(futures)} requests')
            if now >= resend_at:
                futures.append(client.call_async(request))
                resend_at = now + RESEND_S
            self.executor.spin_once(timeout_sec=0.1)
        return next(f for f in futures if f.done()).result()

    def parameters(self, fqn: str, alive=lambda: None) -> dict:
        """{name: value} of every parameter of the node `fqn`; an AssertionError when get_parameters answers
        fewer values than it was asked for (rclpy answers none when one of them is unset). alive() raises when the
        node's process has ended."""
        lister = self.node.create_client(ListParameters, f'{fqn}/list_parameters')
        getter = self.node.create_client(GetParameters, f'{fqn}/get_parameters')
        try:
            names = sorted(self._call(lister, ListParameters.Request(), f'{fqn}/list_parameters', alive).result.names)
            values = self._call(getter, GetParameters.Request(names=names), f'{fqn}/get_parameters', alive).values
        finally:
            self.node.destroy_client(lister)
            self.node.destroy_client(getter)
        assert names, f'{fqn}: list_parameters answered no name'
        assert len(values) == len(names), (f'{fqn}: get_parameters answered {len(values)} values for {len(names)} '
                                           'names (`ros2 param dump` prints {})')
        return {name: _plain(parameter_value_to_python(v)) for name, v in zip(names, values)}

    def close(self):
        self.executor.remove_node(self.node)
        self.node.destroy_node()
        self.executor.shutdown()
        rclpy.shutdown(context=self.ctx)


def _plain(value):
    return list(value) if hasattr(value, 'tolist') or isinstance(value, (tuple,)) else value


@contextmanager
def launched(tmp_path: Path, launch_file: Path, **arguments):
    """The nodes of launch_file (launch arguments as `ros2 launch` takes them) running in a ROS domain of their
    own: yields ({fully qualified name: LaunchedNode}, ParameterReader, alive(fqn)); every process ended after."""
    nodes = evaluate(launch_file, **arguments)
    with isolated_domain() as (domain, env):
        procs, reader = {}, ParameterReader(domain)
        logs = tmp_path / f'logs_{launch_file.stem}_{time.monotonic_ns()}'
        logs.mkdir()

        def alive(fqn):
            def check():
                if procs[fqn].poll() is not None:
                    raise AssertionError(f'{fqn} exited with {procs[fqn].returncode}:\n'
                                         + (logs / f'{fqn.strip("/").replace("/", "_")}.log').read_text()[-3000:])
            return check
        try:
            for node in nodes:
                fqn = f'{node.namespace}/{node.name}'
                argv = node.command(logs, Path(get_package_prefix(node.package)))
                with open(logs / f'{fqn.strip("/").replace("/", "_")}.log', 'w') as log:
                    procs[fqn] = subprocess.Popen(argv, env=env, stdout=log, stderr=subprocess.STDOUT, cwd=tmp_path)
            yield {f'{n.namespace}/{n.name}': n for n in nodes}, reader, alive
        finally:
            for proc in procs.values():
                terminate(proc)
            reader.close()


def launched_parameters(tmp_path: Path, launch_file: Path, **arguments) -> dict:
    """{fully qualified node name: {parameter: value}} of every node launch_file starts, read back from them."""
    with launched(tmp_path, launch_file, **arguments) as (nodes, reader, alive):
        return {fqn: reader.parameters(fqn, alive(fqn)) for fqn in nodes}
