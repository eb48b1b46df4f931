"""`quadflight record --out DIR [TOPIC ...]`: the recorder node in this process until Ctrl-C."""



def add_arguments(parser):
    parser.add_argument('--out', required=True, help='bag directory to create (rosbag2, MCAP storage)')
    parser.add_argument('topics', nargs='*', default=[],
                        help='topics to record (default: the topics quadflight fly records)')
    parser.add_argument('--flush-period', type=float, default=1.0, metavar='S',
                        help='seconds between pushes of the open chunk to disk (default 1.0)')


def ros_arguments(out, topics, flush_period_s=1.0) -> list[str]:
    """--ros-args for the recorder node (also how `fly` starts it as a process)."""
    quoted = ','.join(f'"{t}"' for t in topics)
    return ['--ros-args', '-r', '__node:=recorder', '-p', f'output_dir:={out}', '-p', f'topics:=[{quoted}]',
            '-p', f'flush_period_s:={float(flush_period_s)}']


def run(args) -> int:
    import os
    import sys

    from rclpy.expand_topic_name import expand_topic_name
    from rclpy.validate_full_topic_name import validate_full_topic_name

    from quad_bringup.limits import domain_refusal, ros_name_refusal

    def valid(topic):   # as the recorder's subscription resolves it (rcl refuses e.g. a repeated '/' only there)
        validate_full_topic_name(expand_topic_name(topic, 'recorder', '/'))

    reason = domain_refusal(os.environ) or next(
        (r for t in args.topics if (r := ros_name_refusal('topic', t, valid))), None)
    if reason:   # before the recorder makes --out
        print(f'quadflight record: {reason}', file=sys.stderr)
        return 2
    from quad_bringup.recording import recorder_node
    from quad_bringup.recording.recorder import DEFAULT_TOPICS

    try:
        recorder_node.main(ros_arguments(args.out, args.topics or list(DEFAULT_TOPICS), args.flush_period))
    except SystemExit as exc:
        return int(exc.code or 0)
    return 0
