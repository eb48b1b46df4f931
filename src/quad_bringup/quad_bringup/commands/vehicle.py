"""`quadflight arm|offboard|land`: the bridge's std_srvs services from a machine without the ros2 CLI (the PyPI
wheels carry rclpy, not ros2cli). The ROS domain is the environment's ROS_DOMAIN_ID, as for every node."""

import sys
import time

SERVICES = {  # command -> (service, type name, help)
    'arm': ('arm', 'SetBool', 'arm the vehicle (--off disarms)'),
    'offboard': ('offboard', 'SetBool', "hand the vehicle to the controller's setpoints: PX4 OFFBOARD, ArduPilot "
                                        'GUIDED_NOGPS (--off ends it: AUTO.LOITER / LAND)'),
    'land': ('land', 'Trigger', 'end the hand-over and land (AUTO.LAND / LAND)'),
}


def add_arguments(parser):
    parser.add_argument('--namespace', default='/', help="the bridge's namespace (default /)")
    parser.add_argument('--timeout-s', type=float, default=10.0, metavar='S',
                        help='wait this long for the bridge and its answer (default 10)')
    parser.add_argument('--off', action='store_true', help='arm: disarm; offboard: end the hand-over')


def run(args) -> int:
    import os

    from quad_bringup.limits import domain_refusal, ros_name_refusal

    command = args.command
    service, kind, _ = SERVICES[command]
    reason = domain_refusal(os.environ)
    if not reason and not (0.0 < args.timeout_s <= 600.0):
        reason = f'--timeout-s {args.timeout_s:g} refused: must be > 0 and <= 600 s'
    if not reason and args.off and kind != 'SetBool':
        reason = f'--off refused: {command} has no off'
    if not reason:   # rclpy's rule (rclpy imported: after the checks that need none)
        from rclpy.validate_namespace import validate_namespace

        reason = ros_name_refusal('--namespace', args.namespace, lambda ns: validate_namespace('/' + ns.lstrip('/')))
    if reason:
        print(f'quadflight {command}: {reason}', file=sys.stderr)
        return 2
    import rclpy
    from std_srvs.srv import SetBool, Trigger

    srv_type = SetBool if kind == 'SetBool' else Trigger
    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        node = rclpy.create_node('quadflight_cli', namespace=args.namespace, context=context,
                                 start_parameter_services=False)
        client = node.create_client(srv_type, service)
        name = f'{args.namespace.rstrip("/")}/{service}'
        if not client.wait_for_service(timeout_sec=args.timeout_s):
            print(f'quadflight {command}: no mavlink_bridge offers {name} (ROS domain from ROS_DOMAIN_ID, '
                  f'namespace {args.namespace}) within {args.timeout_s:g} s', file=sys.stderr)
            return 2
        request = SetBool.Request(data=not args.off) if kind == 'SetBool' else Trigger.Request()
        future = client.call_async(request)
        deadline = time.monotonic() + args.timeout_s
        executor = rclpy.executors.SingleThreadedExecutor(context=context)
        executor.add_node(node)
        while not future.done() and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.1)
        if not future.done():
            print(f'quadflight {command}: {name}: no answer within {args.timeout_s:g} s', file=sys.stderr)
            return 2
        answer = future.result()
        print(f'{name}: {"accepted" if answer.success else "refused"}: {answer.message}',
              file=sys.stdout if answer.success else sys.stderr)
        return 0 if answer.success else 1
    finally:
        context.try_shutdown()
