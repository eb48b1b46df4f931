"""A disturbance profiles file (config/disturbances.yaml) by name, in pure Python: the entry a profile name means, so
a command refuses an unknown name before numpy is imported (quad_sim.disturbances checks the entry's fields)."""

from quad_common.yaml_io import load_yaml


def profile_entry(path, name: str):
    """The mapping of profile `name` in the file (None for `none`, which always exists); ValueError naming the
    known ones for any other name the file does not hold."""
    profiles = load_yaml(path)
    if name == 'none' and name not in profiles:
        return None
    if name not in profiles:
        raise ValueError(f'disturbances = {name!r}: no such profile in {path}; known: {sorted(profiles)}')
    return profiles[name]
