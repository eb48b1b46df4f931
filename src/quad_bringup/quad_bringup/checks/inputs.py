"""fly's input files checked before anything starts: the control profile (quad_bringup.checks.profiles) and the
disturbance profile name in the file sim_node will read it from (config/disturbances.yaml, or the
`disturbances_file` a sweep writes for its spec's profiles), which the graph's nodes would otherwise refuse only
after the start (a run directory and an empty bag left, or the defaults flown with exit 0); and a bag that is not
there, which every bag reader refuses first (pure Python: a command says it before importing the readers)."""


def check_inputs(options):
    """Raises ValueError naming the option, the file and the problem."""
    from quad_common.paths import resolve_config

    if options.control_profile is not None:
        from quad_bringup.checks.profiles import check_control_profile

        try:
            check_control_profile(options.control_profile)
        except ValueError as exc:
            raise ValueError(f'--control-profile {exc}') from None
    if options.disturbances is not None:
        from quad_sim.disturbance_file import profile_entry

        source = (options.sim_parameters or {}).get('disturbances_file') or 'config/disturbances.yaml'
        try:
            profile_entry(resolve_config(source), options.disturbances)   # the name, before numpy
            from quad_sim.disturbances import load_profile

            load_profile(resolve_config(source), options.disturbances)    # its fields
        except ValueError as exc:
            raise ValueError(f'--disturbances: {exc}') from None


def same_file(a, b) -> bool:
    """a and b name one file (or a does not exist yet and resolves to b's path)."""
    import os
    from pathlib import Path
    a, b = Path(a), Path(b)
    try:
        return os.path.samefile(a, b)
    except OSError:
        return a.resolve() == b.resolve()


def check_bag_dir(bag_dir):
    """Raises FileNotFoundError when bag_dir is not a directory (a rosbag2 bag is one)."""
    import os

    if not os.path.isdir(bag_dir):
        raise FileNotFoundError(f'bag {bag_dir}: no such directory')
